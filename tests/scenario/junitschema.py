"""Jenkins' JUnit XML schema (``junit-10.xsd``, from the Jenkins xunit plugin, MIT) for the
tests, fetched at test time and never committed: pytest's source distribution carries it
(``testing/example_scripts/junit-10.xsd``, which pytest validates its own --junitxml
against), checked against its SHA-256 and cached under the virtual environment
(tests/sdistschema.py).

``python -m tests.scenario.junitschema`` fetches it (scripts/test.sh does, before the tests).
"""

from __future__ import annotations

from tests.sdistschema import SdistSchema

JUNIT = SdistSchema("pytest==9.2.0", "pytest-9.2.0/testing/example_scripts/junit-10.xsd",
                    "a1a816f58d1bf95ebabf371994df0b9246dee66ea9572fbec4f9296f1b2c0ff6")

if __name__ == "__main__":
    JUNIT.main()
