"""Verdict on a pytest JUnit XML file: exit 1 unless tests ran and every one passed.

A suite that was skipped, deselected or collected nothing fails, so a broken test
environment (no vcan, a VM that did not boot) can never pass silently. Properties the tests
recorded with ``record_property`` (latencies, bus loads) are printed as a report.

Usage: ``python scripts/check_junit.py RESULTS.xml``
"""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class Tally:
    """Counts of test cases by outcome, and the recorded properties per test."""

    passed: int = 0
    failed: int = 0
    skipped: int = 0
    properties: dict[str, list[tuple[str, str]]] = field(default_factory=dict)


def outcome(case: ET.Element) -> str:
    """'failed', 'skipped' or 'passed' for one ``<testcase>`` element."""
    if case.find("failure") is not None or case.find("error") is not None:
        return "failed"
    return "skipped" if case.find("skipped") is not None else "passed"


def tally(path: Path) -> Tally:
    """Counts every ``<testcase>`` in the file at ``path``."""
    result = Tally()
    for case in ET.parse(path).getroot().iter("testcase"):
        kind = outcome(case)
        setattr(result, kind, getattr(result, kind) + 1)
        props = [(p.get("name", ""), p.get("value", "")) for p in case.iter("property")]
        if props:
            result.properties[case.get("name", "?")] = props
    return result


def verdict(result: Tally) -> str | None:
    """None when the suite counts as run and green, else what was wrong."""
    if result.passed + result.failed + result.skipped == 0:
        return "no test was collected"
    if result.failed:
        return f"{result.failed} test(s) failed or errored"
    if result.skipped:
        return f"{result.skipped} test(s) were skipped; the vcan suite must run in full"
    return None


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: check_junit.py RESULTS.xml", file=sys.stderr)
        return 2
    path = Path(argv[0])
    if not path.is_file():
        print(f"check_junit: error: no results at {path} (the run did not reach pytest)",
              file=sys.stderr)
        return 1
    result = tally(path)
    for test, props in result.properties.items():
        for name, value in props:
            print(f"check_junit: {test}: {name} = {value}")
    problem = verdict(result)
    print(f"check_junit: {result.passed} passed, {result.failed} failed, "
          f"{result.skipped} skipped")
    if problem:
        print(f"check_junit: error: {problem}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
