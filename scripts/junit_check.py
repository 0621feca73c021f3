#!/usr/bin/env python3
"""Reads vinebench's JUnit XML with two independent JUnit readers from PyPI (junitparser
and xunitparser, the kinds CI servers' plugins use) and checks that both see the same
suites, cases, failures and errors, and the counts given on the command line.

    python3 scripts/junit_check.py FILE --tests N [--failures F] [--errors E] [--suites S]

Exit code 0 when both readers agree with each other and with the expected counts.
Install the readers with: python3 -m pip install --user junitparser xunitparser
"""

import argparse
import sys

import junitparser
import xunitparser


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("file")
    ap.add_argument("--tests", type=int, required=True)
    ap.add_argument("--failures", type=int, default=0)
    ap.add_argument("--errors", type=int, default=0)
    ap.add_argument("--suites", type=int)
    a = ap.parse_args()

    # junitparser: the document's own counts and the cases it finds.
    xml = junitparser.JUnitXml.fromfile(a.file)
    suites = list(xml) if isinstance(xml, junitparser.JUnitXml) else [xml]
    cases = [c for s in suites for c in s]
    jp = {
        "suites": len(suites),
        "tests": len(cases),
        "failures": sum(1 for c in cases for r in c.result if isinstance(r, junitparser.Failure)),
        "errors": sum(1 for c in cases for r in c.result if isinstance(r, junitparser.Error)),
    }
    declared = {"tests": xml.tests, "failures": xml.failures, "errors": xml.errors}

    # xunitparser: a unittest-style result.
    with open(a.file, "rb") as f:
        _suite, tr = xunitparser.parse(f)
    xp = {"tests": tr.testsRun, "failures": len(tr.failures), "errors": len(tr.errors)}

    want = {"tests": a.tests, "failures": a.failures, "errors": a.errors}
    problems = []
    for name, got in (("junitparser cases", jp), ("junitparser totals", declared), ("xunitparser", xp)):
        for k, v in want.items():
            if got[k] != v:
                problems.append(f"{name}: {k} = {got[k]}, expected {v}")
    if a.suites is not None and jp["suites"] != a.suites:
        problems.append(f"junitparser: {jp['suites']} suites, expected {a.suites}")
    for c in cases:
        if not c.name or not c.classname:
            problems.append(f"a test case without name or classname: {c!r}")
    print(f"{a.file}: {jp['suites']} suites, {jp['tests']} cases, {jp['failures']} failures, "
          f"{jp['errors']} errors (junitparser {junitparser.version}; xunitparser agrees: "
          f"{xp == {k: jp[k] for k in xp}})")
    if problems:
        print("\n".join(problems), file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
