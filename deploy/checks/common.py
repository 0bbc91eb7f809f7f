"""Small helpers shared by the deploy checks (Python 3.11 standard library only)."""

import os
import sys

VERBOSE = os.environ.get("CHECK_DEPLOY_VERBOSE") == "1"


class Report:
    """Collects failures and prints them at the end; exits 1 if there were any."""

    def __init__(self, name: str):
        self.name = name
        self.failures: list[str] = []
        self.passed = 0

    def fail(self, message: str) -> None:
        self.failures.append(message)
        print(f"  FAIL {message}")

    def ok(self, message: str) -> None:
        self.passed += 1
        if VERBOSE:
            print(f"  ok   {message}")

    def check(self, condition: bool, message: str) -> bool:
        (self.ok if condition else self.fail)(message)
        return condition

    def finish(self) -> None:
        if self.failures:
            print(f"  {self.name}: {len(self.failures)} problem(s), {self.passed} checks passed")
            sys.exit(1)
        print(f"  {self.name}: all {self.passed} checks passed" + ("" if VERBOSE else " (CHECK_DEPLOY_VERBOSE=1 lists them)"))


def dashboard_panels(dashboard: dict) -> list[dict]:
    """Every panel, including those nested in collapsed rows."""
    out = []
    for panel in dashboard.get("panels", []):
        out.append(panel)
        out.extend(panel.get("panels", []))
    return out


def uses_datasource_variable(ref, name: str = "datasource") -> bool:
    """A datasource reference that names the dashboard variable."""
    forms = {f"${name}", f"${{{name}}}"}
    if isinstance(ref, str):
        return ref in forms
    return isinstance(ref, dict) and ref.get("uid") in forms
