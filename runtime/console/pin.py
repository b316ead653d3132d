"""Console PINs: stored as a salted PBKDF2 hash in the plant file, never in clear."""

from __future__ import annotations

import hashlib
import hmac
import os

#: PBKDF2-SHA256 iterations: ~0.1 s on a Raspberry Pi 4, slows down guessing
ITERATIONS = 100_000


def hash_pin(pin: str, salt: bytes | None = None, iterations: int = ITERATIONS) -> str:
    """``pbkdf2_sha256$ITER$SALT_HEX$HASH_HEX`` for ``pin``."""
    salt = salt if salt is not None else os.urandom(16)
    digest = hashlib.pbkdf2_hmac("sha256", pin.encode(), salt, iterations)
    return f"pbkdf2_sha256${iterations}${salt.hex()}${digest.hex()}"


def check_pin(pin: str, stored: str) -> bool:
    """True if ``pin`` matches ``stored`` (constant-time compare)."""
    try:
        algo, iters, salt_hex, hash_hex = stored.split("$")
        if algo != "pbkdf2_sha256":
            return False
        digest = hashlib.pbkdf2_hmac("sha256", pin.encode(), bytes.fromhex(salt_hex),
                                     int(iters))
    except ValueError:
        return False
    return hmac.compare_digest(digest.hex(), hash_hex)
