"""JUnit XML of a ``softplc test`` run, as CI systems read it (Jenkins, GitLab, GitHub
Actions' test reporters): one ``testsuite`` per scenario file, one ``testcase`` per
expectation (and one named ``run`` for a scan fault), a failure's line as its ``failure``,
a scenario that cannot run as one ``testcase`` with an ``error``. It validates against
Jenkins' JUnit schema (junit-10.xsd, as tests/scenario/junitschema.py fetches it)."""

from __future__ import annotations

import datetime
import socket
import xml.etree.ElementTree as ET

from runtime.scenario.run import Outcome


def _seconds(s: float) -> str:
    """A duration as the schema's SUREFIRE_TIME wants it: at most three decimals."""
    return f"{s:.3f}"


def junit_xml(outcomes: list[Outcome], errors: list[str], seconds: float) -> str:
    """The report's text. ``errors``: the paths of the command line that named nothing
    (each one suite in error)."""
    stamp = datetime.datetime.now().replace(microsecond=0).isoformat()
    host = socket.gethostname()
    suites = ET.Element("testsuites", name="softplc test", time=_seconds(seconds))
    n_tests = n_failures = n_errors = 0
    for o in outcomes:
        failures = len(o.failed)
        suite = ET.SubElement(suites, "testsuite", name=o.path,
                              tests=str(len(o.cases) or 1), failures=str(failures),
                              errors="1" if o.error is not None else "0", skipped="0",
                              time=_seconds(o.seconds), timestamp=stamp, hostname=host,
                              file=o.path)
        if o.error is not None:
            case = ET.SubElement(suite, "testcase", name="load", classname=o.path, time="0.000")
            ET.SubElement(case, "error", message=o.error, type="file").text = o.error
            n_tests, n_errors = n_tests + 1, n_errors + 1
            continue
        for c in o.cases:
            case = ET.SubElement(suite, "testcase", name=c.name, classname=o.path,
                                 time="0.000")
            if c.failure is not None:
                ET.SubElement(case, "failure", message=c.failure,
                              type="expectation" if c.name != "run" else "scan fault"
                              ).text = c.failure
        ET.SubElement(suite, "system-out").text = f"{o.scans} scans"
        n_tests += len(o.cases)
        n_failures += failures
    for line in errors:
        path = line.split(":", 1)[0]
        suite = ET.SubElement(suites, "testsuite", name=path, tests="1", failures="0",
                              errors="1", skipped="0", time="0.000", timestamp=stamp,
                              hostname=host)
        case = ET.SubElement(suite, "testcase", name="load", classname=path, time="0.000")
        ET.SubElement(case, "error", message=line, type="file").text = line
        n_tests, n_errors = n_tests + 1, n_errors + 1
    suites.set("tests", str(n_tests))
    suites.set("failures", str(n_failures))
    suites.set("errors", str(n_errors))
    ET.indent(suites)
    return ET.tostring(suites, encoding="unicode", xml_declaration=True) + "\n"
