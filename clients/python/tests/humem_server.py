"""Test helper: runs the real ``humem serve`` binary on a free loopback port
with a temporary store, as tests/e2e/harness.rs and the C++ client's tests
do, and makes data the tests send (descriptors, TLS material, tokens).

The binary is $HUMEM_BIN (default: <repo>/target/debug/humem; a relative
path is taken from the repository root); the models are <repo>/models
(scripts/setup-models.sh).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
import threading
import time
import unittest
from pathlib import Path
from typing import Dict, Optional

import numpy as np

REPO = Path(__file__).resolve().parents[3]


def require(available: bool, what: str) -> None:
    """Skips the calling test (class) when ``what`` is missing, or fails it
    under HUMEM_CLIENT_STRICT=1, as scripts/test-client-python.sh (CI) sets."""
    if available:
        return
    if os.environ.get("HUMEM_CLIENT_STRICT"):
        raise RuntimeError(f"{what} is missing (HUMEM_CLIENT_STRICT is set: not skipping)")
    raise unittest.SkipTest(f"{what} is missing")


def humem_bin() -> Path:
    value = os.environ.get("HUMEM_BIN", "target/debug/humem")
    path = Path(value)
    if not path.is_absolute():
        path = REPO / path
    if not os.access(path, os.X_OK):
        raise RuntimeError(
            f"humem binary not found or not executable at {path} "
            "(build it with `cargo build --locked --bin humem`, or set HUMEM_BIN)"
        )
    return path


def clean_env(extra: Dict[str, str]) -> Dict[str, str]:
    """Our environment less every HUMEM_* variable (the server refuses
    unknown ones, e.g. HUMEM_BIN) and RUST_LOG, plus ``extra``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("HUMEM_") and k != "RUST_LOG"}
    env.update(extra)
    return env


class HumemServer:
    """A running ``humem serve``; use as a context manager or call stop().

    Perception is off unless asked for (precomputed features start faster).
    Scores use the paper's raw rule (``vpr.calibration = "raw"``): the tests
    store a handful of keyframes, too few for the calibrated null, and what
    they check is the client, not the scoring.
    """

    def __init__(self, *, perception: bool = False, env: Optional[Dict[str, str]] = None):
        self.dir = Path(tempfile.mkdtemp(prefix="humem-client-python-"))
        self.log_path = self.dir / "server.log"
        settings = {
            "RUST_LOG": "warn,ort::logging=error",
            "HUMEM_PERCEPTION__ENABLED": "true" if perception else "false",
            "HUMEM_PERCEPTION__MODELS_DIR": str(REPO / "models"),
            "HUMEM_METRICS__LISTEN": "127.0.0.1:0",
            "HUMEM_VPR__CALIBRATION": "raw",
        }
        settings.update(env or {})
        log = open(self.log_path, "wb")
        self.process = subprocess.Popen(
            [str(humem_bin()), "serve", "--listen", "127.0.0.1:0", "--data-dir", str(self.dir / "data")],
            env=clean_env(settings),
            stdout=subprocess.PIPE,
            stderr=log,
        )
        log.close()
        found = threading.Event()
        self.address = ""

        def read() -> None:
            for raw in self.process.stdout:
                line = raw.decode(errors="replace").strip()
                if line.startswith("humem listening on "):
                    self.address = line[len("humem listening on "):]
                    found.set()
            found.set()  # exited

        threading.Thread(target=read, daemon=True).start()
        if not found.wait(60) or not self.address:
            log = self.log()
            self.stop()
            raise RuntimeError(f"humem serve ({humem_bin()}) did not report its address; its log:\n{log}")
        self.port = int(self.address.rsplit(":", 1)[1])

    @property
    def url(self) -> str:
        return f"http://{self.address}"

    @property
    def https(self) -> str:
        return f"https://{self.address}"

    def log(self) -> str:
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return ""
        return text if len(text) <= 3000 else text[:3000] + "\n[...]"

    def freeze(self) -> None:
        """SIGSTOP: requests sent now wait until thaw()."""
        self.process.send_signal(signal.SIGSTOP)

    def thaw(self) -> None:
        self.process.send_signal(signal.SIGCONT)

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGCONT)
            self.process.terminate()
            try:
                self.process.wait(30)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self.process.stdout:
            self.process.stdout.close()
        shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> "HumemServer":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def make_tls_dir(dir: Path) -> Path:
    """A CA, a server certificate for localhost and 127.0.0.1 (openssl, via
    scripts/make-dev-certs.sh) in ``dir``, and another CA in dir/other."""
    for sub, names in ((dir, ["localhost", "127.0.0.1"]), (dir / "other", ["localhost"])):
        subprocess.run(
            [str(REPO / "scripts/make-dev-certs.sh"), str(sub), *names],
            check=True,
            stdout=subprocess.DEVNULL,
        )
    return dir


def add_token(tokens_file: Path, robot: str, admin: bool = False) -> str:
    """``humem token add``: a new token for ``robot``, written to the token file."""
    args = [str(humem_bin()), "token", "add", "--file", str(tokens_file), "--robot", robot]
    if admin:
        args += ["--role", "admin"]
    done = subprocess.run(args, env=clean_env({}), capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"humem token add failed: {done.stderr}")
    return done.stdout.strip()


def unit(v: np.ndarray) -> np.ndarray:
    return (v / np.linalg.norm(v)).astype(np.float32)


def random_descriptor(seed: int, dim: int = 64) -> np.ndarray:
    """A random unit descriptor; different seeds give nearly orthogonal ones."""
    return unit(np.random.default_rng(seed).standard_normal(dim))


def near(descriptor: np.ndarray, seed: int, noise: float = 0.05) -> np.ndarray:
    """``descriptor`` with a little noise: what a revisit looks like."""
    return unit(descriptor + noise * np.random.default_rng(10_000 + seed).standard_normal(descriptor.size))


def wait_until(predicate, timeout: float = 10.0, interval: float = 0.01) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval)
    return predicate()
