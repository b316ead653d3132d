"""A wire between two lines of a gpio-sim chip, for the real-chip loop-back test of
tests/drivers/test_gpio.py inside the kernel_io guest: the level of line OUT (an output)
drives line IN (an input) through its simulated pull, as a jumper between two pins of a
board would. Polled every millisecond; runs until killed. Standard library only.

Usage: python -I -S simwire.py SYSFS_DIR_OF_THE_CHIP OUT IN
"""

from __future__ import annotations

import sys
import time


def main(chip: str, out: int, inp: int) -> None:
    value = f"{chip}/sim_gpio{out}/value"
    pull = f"{chip}/sim_gpio{inp}/pull"
    while True:
        with open(value, encoding="ascii") as f:
            want = "pull-up" if f.read().strip() == "1" else "pull-down"
        with open(pull, encoding="ascii") as f:
            have = f.read().strip()
        if have != want:  # a bias set by a request changes the pull too: put it back
            with open(pull, "w", encoding="ascii") as f:
                f.write(want)
        time.sleep(0.001)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]))
