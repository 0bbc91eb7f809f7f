"""The README's example, examples/quickstart.py, runs against the real
server with its default scoring (calibrated threshold) and finds the
revisited place."""

import subprocess
import sys
import unittest
from pathlib import Path

from humem_server import HumemServer

SCRIPT = Path(__file__).resolve().parents[1] / "examples" / "quickstart.py"


class QuickstartTest(unittest.TestCase):
    def test_the_example_runs(self):
        with HumemServer(env={"HUMEM_VPR__CALIBRATION": "null"}) as server:
            done = subprocess.run([sys.executable, str(SCRIPT), server.url], capture_output=True, text=True,
                                  timeout=120)
        self.assertEqual(done.returncode, 0, done.stdout + done.stderr)
        self.assertTrue(done.stdout.startswith("candidate keyframe 5: score"), done.stdout)
        self.assertIn("latest-wins ticket 1: answered, best keyframe 5", done.stdout)
        self.assertIn("refused as expected: INVALID_ARGUMENT: keyframe.features.global_descriptor", done.stdout)
        self.assertIn("erased 1 keyframe", done.stdout)
        self.assertIn("store: 19 keyframes of 256 values", done.stdout)


if __name__ == "__main__":
    unittest.main()
