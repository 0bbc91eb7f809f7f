"""Runs a tool test's checks and prints one line each and the closing count.

Each check returns (ok, detail); a check that raises fails alone, not the run.
The closing line `N passed, N failed` is what CI reads; the exit status is 1
if any check failed.
"""

import sys


def run(checks):
    passed = failed = 0
    for check in checks:
        try:
            ok, detail = check()
        except Exception as e:  # a crash is a failure of that check, not of the run
            ok, detail = False, f'{type(e).__name__}: {e}'
        passed, failed = passed + ok, failed + (not ok)
        print(f'{"PASS" if ok else "FAIL"} {check.__name__[6:]}: {detail}')
    print(f'{passed} passed, {failed} failed')
    sys.exit(1 if failed else 0)
