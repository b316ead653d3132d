"""Console PINs and the passwords of OPC UA and web users: stored as a salted scrypt hash
in the plant file, never in clear (one home: the console, the OPC UA server and the web
view check them here; ``Passwords`` holds a user's checks from an address after a failed
one, and hashes an unknown user's password as a known one's).

A PIN is short, so whoever can read the plant file can try every PIN offline: the hash is
made slow and memory-hard on purpose. scrypt with N=2**15, r=8, p=4 uses 32 MiB and takes
about 0.2 s per guess on a 2020s x86 server core (measured), an estimated 1 s on a
Raspberry Pi 4 core: searching every 4-digit PIN costs hours, 6 digits weeks. hashlib runs
the hash with the GIL released (CPython ``_hashopenssl.c``: ``Py_BEGIN_ALLOW_THREADS``
around ``EVP_PBE_scrypt``), so an unlock never stalls the scan thread. Hashes of the old
``pbkdf2_sha256$`` format still verify, with a warning to make a new one.
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import math
import os
import threading
import time
from collections.abc import Callable

log = logging.getLogger(__name__)

#: scrypt cost: N (CPU/memory cost, a power of 2), r (block size), p (sequential lanes)
SCRYPT_N = 2**15
SCRYPT_R = 8
SCRYPT_P = 4
#: memory allowed to one check, bytes: the default cost needs 128*N*r = 32 MiB; a stored
#: hash asking for more is refused rather than computed
SCRYPT_MAXMEM = 64 * 1024 * 1024
#: the old format's iterations, and the most a stored old hash may ask for
ITERATIONS = 100_000
MAX_ITERATIONS = 10_000_000
#: one check at a time: each costs 32 MiB and a core, whatever the number of consoles
_CHECKING = threading.Lock()


def hash_pin(pin: str, salt: bytes | None = None, n: int = SCRYPT_N, r: int = SCRYPT_R,
             p: int = SCRYPT_P, iterations: int | None = None) -> str:
    """``scrypt$N$R$P$SALT_HEX$HASH_HEX`` for ``pin``. Cheaper costs are for tests only;
    ``iterations`` makes the old ``pbkdf2_sha256$ITER$SALT_HEX$HASH_HEX`` format (tests
    of old plant files)."""
    salt = salt if salt is not None else os.urandom(16)
    if iterations is not None:
        digest = hashlib.pbkdf2_hmac("sha256", pin.encode(), salt, iterations)
        return f"pbkdf2_sha256${iterations}${salt.hex()}${digest.hex()}"
    digest = hashlib.scrypt(pin.encode(), salt=salt, n=n, r=r, p=p, maxmem=SCRYPT_MAXMEM,
                            dklen=32)
    return f"scrypt${n}${r}${p}${salt.hex()}${digest.hex()}"


def check_pin(pin: str, stored: str) -> bool:
    """True if ``pin`` matches ``stored`` (constant-time compare). A malformed hash, or one
    costing more than SCRYPT_MAXMEM or MAX_ITERATIONS, matches nothing."""
    algo, _, rest = stored.partition("$")
    try:
        with _CHECKING:
            if algo == "scrypt":
                n, r, p, salt_hex, hash_hex = rest.split("$")
                digest = hashlib.scrypt(pin.encode(), salt=bytes.fromhex(salt_hex), n=int(n),
                                        r=int(r), p=int(p), maxmem=SCRYPT_MAXMEM, dklen=32)
            elif algo == "pbkdf2_sha256":
                iters, salt_hex, hash_hex = rest.split("$")
                if not 0 < int(iters) <= MAX_ITERATIONS:
                    return False
                log.warning("the plant's pin_hash is of the old pbkdf2_sha256 format, fast "
                            "to search offline: make a new one with 'softplc hash-pin'")
                digest = hashlib.pbkdf2_hmac("sha256", pin.encode(),
                                             bytes.fromhex(salt_hex), int(iters))
            else:
                return False
    except (ValueError, OverflowError):  # also OpenSSL's refusal of a cost, or no memory for it
        return False
    except MemoryError:
        log.error("PIN check: no memory for the hash (scrypt needs %d MiB; with "
                  "realtime: lock_memory, raise LimitMEMLOCK)", 128 * SCRYPT_N * SCRYPT_R >> 20)
        return False
    return hmac.compare_digest(digest.hex(), hash_hex)


#: after a failed password check, that user's checks from that address are refused
#: without hashing this long, s (the OPC UA server's and the web view's logins)
FAIL_HOLD_S = 1.0
#: what ``Passwords.verify`` answers: the password is right; refused without hashing (a
#: failed check of that user from that address less than FAIL_HOLD_S ago, or one being
#: hashed); refused without hashing (another check from that address is being hashed);
#: hashed and wrong (or no such user)
OK, HELD, BUSY, WRONG = "ok", "held", "busy", "wrong"


class Passwords:
    """The users of a side process (OPC UA ``security: users``, ``web: users``) and their
    hashes, checked with the same rules everywhere (docs/web.md, "Acting from the page"):

    - after a failed check, that user's checks *from that address* are refused without
      hashing for FAIL_HOLD_S: guessing costs one hash per second, user name and address,
      and a stranger's guesses never hold the operator's logins from another address
      (the OPC UA server passes no address: its clients are one);
    - the hold is taken, under a lock, before hashing: checks sent at once are not all
      hashed; an address has one check hashed at a time (others from it are refused at
      once), and the hashes themselves run one at a time (``check_pin``): hashing never
      takes more than one core, whatever the number of addresses;
    - an unknown user's password is hashed too, against a stand-in of the first user's
      cost, and held the same way: the time of a refusal does not tell which user names
      exist;
    - a successful check is remembered as an HMAC under a key drawn at start (never the
      password): logging in again costs no hash and is never held."""

    def __init__(self, users: dict[str, str],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.users = users
        self._clock = clock
        self._key = os.urandom(32)
        self._known: set[bytes] = set()
        self._lock = threading.Lock()
        #: (user, address) -> clock seconds until which its checks are refused
        self._hold_until: dict[tuple[str, str | None], float] = {}
        #: the addresses whose check is being hashed
        self._checking: set[str | None] = set()
        self._stand_in = stand_in(next(iter(users.values()), None))

    def check(self, user: str, password: str, source: str | None = None) -> bool:
        """Whether ``password`` is ``user``'s (``verify`` is OK)."""
        return self.verify(user, password, source) == OK

    def verify(self, user: str, password: str, source: str | None = None) -> str:
        """OK, HELD, BUSY or WRONG for ``password`` of ``user`` from the address ``source``
        (None: the caller knows none). Hashes at most once; thread-safe."""
        stored = self.users.get(user)
        tag = hmac.new(self._key, f"{user}\0{password}\0{stored}".encode(),
                       hashlib.sha256).digest()
        key = (user, source)
        with self._lock:
            if stored is not None and tag in self._known:
                return OK
            now = self._clock()
            if now < self._hold_until.get(key, 0.0):
                return HELD
            if source in self._checking:
                return BUSY
            self._checking.add(source)
            self._hold_until[key] = math.inf  # held while it is hashed
            if len(self._hold_until) > MAX_HOLDS:
                self._hold_until = {k: t for k, t in self._hold_until.items() if t > now}
        ok = False
        try:
            ok = check_pin(password, self._stand_in if stored is None else stored)
            ok = ok and stored is not None
        finally:
            with self._lock:
                self._checking.discard(source)
                if ok:
                    self._hold_until.pop(key, None)
                    self._known.add(tag)
                else:
                    self._hold_until[key] = self._clock() + FAIL_HOLD_S
        return OK if ok else WRONG


#: holds kept before the expired ones are dropped (each failed check adds one)
MAX_HOLDS = 1024


def stand_in(stored: str | None) -> str:
    """A hash no password matches, of the same algorithm and cost as ``stored`` (the
    default cost without one): what an unknown user's password is checked against."""
    if stored is None or stored.count("$") < 3:
        stored = f"scrypt${SCRYPT_N}${SCRYPT_R}${SCRYPT_P}${'0' * 32}${'0' * 64}"
    head, salt, digest = stored.rsplit("$", 2)
    return f"{head}${os.urandom(max(1, len(salt) // 2)).hex()}${os.urandom(32).hex()}"
