"""The committed stubs (humem_client/proto/) are what grpcio-tools makes of
proto/humem/v1/humem.proto today: a change to the .proto that was not
regenerated with generate_stubs.py fails here, and so in CI."""

import importlib.util
import subprocess
import sys
import unittest
from pathlib import Path

from humem_server import require

SCRIPT = Path(__file__).resolve().parents[1] / "generate_stubs.py"


class StubsTest(unittest.TestCase):
    def test_the_committed_stubs_match_the_proto(self):
        require(importlib.util.find_spec("grpc_tools") is not None,
                "grpcio-tools (pinned in scripts/setup-models.sh)")
        done = subprocess.run([sys.executable, str(SCRIPT), "--check"], capture_output=True, text=True)
        self.assertEqual(done.returncode, 0, done.stdout + done.stderr)


if __name__ == "__main__":
    unittest.main()
