#!/usr/bin/env python3
"""Generates the gRPC stubs of humem_client from the repository's proto/.

Runs grpcio-tools' protoc on ``proto/humem/v1/humem.proto`` and writes
``humem_client/proto/humem_pb2.py``, ``humem_pb2.pyi`` and
``humem_pb2_grpc.py``; the generated import of the messages module is made
package-relative so that the stubs live inside ``humem_client``.

    python generate_stubs.py            # regenerate after changing the .proto
    python generate_stubs.py --check    # exit 1 if the committed stubs are stale

The stubs are committed, so ``pip install`` needs no grpcio-tools; the
client's tests run ``--check``, so a change to the .proto that was not
regenerated fails CI. Needs the grpcio-tools pinned in
scripts/setup-models.sh (its protoc is what makes the bytes reproducible).
"""

from __future__ import annotations

import argparse
import difflib
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
PROTO_ROOT = HERE.parent.parent / "proto"
PROTO_FILE = "humem/v1/humem.proto"
OUT_DIR = HERE / "humem_client" / "proto"
# Generated name -> name inside humem_client/proto/.
OUTPUTS = {
    "humem/v1/humem_pb2.py": "humem_pb2.py",
    "humem/v1/humem_pb2.pyi": "humem_pb2.pyi",
    "humem/v1/humem_pb2_grpc.py": "humem_pb2_grpc.py",
}
ABSOLUTE_IMPORT = "from humem.v1 import humem_pb2 as humem_dot_v1_dot_humem__pb2"
RELATIVE_IMPORT = "from . import humem_pb2 as humem_dot_v1_dot_humem__pb2"


def generate() -> dict[str, bytes]:
    """Runs protoc into a temporary folder; returns {file name: contents}."""
    try:
        from grpc_tools import protoc
    except ImportError as e:
        raise SystemExit(
            f"generate_stubs: grpcio-tools is not installed ({e}); it is pinned in "
            "scripts/setup-models.sh (models/.venv has it)"
        )
    if not (PROTO_ROOT / PROTO_FILE).is_file():
        raise SystemExit(f"generate_stubs: {PROTO_ROOT / PROTO_FILE} not found (run from a checkout)")
    with tempfile.TemporaryDirectory() as tmp:
        args = [
            "grpc_tools.protoc",
            f"--proto_path={PROTO_ROOT}",
            f"--python_out={tmp}",
            f"--pyi_out={tmp}",
            f"--grpc_python_out={tmp}",
            PROTO_FILE,
        ]
        rc = protoc.main(args)
        if rc != 0:
            raise SystemExit(f"generate_stubs: protoc failed with exit status {rc}")
        files = {}
        for generated, name in OUTPUTS.items():
            data = (Path(tmp) / generated).read_bytes()
            if name == "humem_pb2_grpc.py":
                text = data.decode()
                if ABSOLUTE_IMPORT not in text:
                    raise SystemExit(f"generate_stubs: {generated} lacks the line {ABSOLUTE_IMPORT!r}")
                data = text.replace(ABSOLUTE_IMPORT, RELATIVE_IMPORT).encode()
            files[name] = data
        return files


def check(files: dict[str, bytes]) -> list[str]:
    """The names of the committed stubs that differ from `files`, with a diff printed."""
    stale = []
    for name, data in files.items():
        path = OUT_DIR / name
        committed = path.read_bytes() if path.exists() else b""
        if committed != data:
            stale.append(name)
            diff = difflib.unified_diff(
                committed.decode(errors="replace").splitlines(),
                data.decode(errors="replace").splitlines(),
                f"committed {name}",
                f"generated {name}",
                lineterm="",
                n=1,
            )
            print("\n".join(line[:160] for line in list(diff)[:40]), file=sys.stderr)
    return stale


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare instead of writing; exit 1 if stale")
    args = parser.parse_args()
    files = generate()
    if args.check:
        stale = check(files)
        if stale:
            print(
                f"generate_stubs: {', '.join(stale)} in {OUT_DIR} do not match {PROTO_ROOT / PROTO_FILE}; "
                f"run `models/.venv/bin/python {Path(__file__).relative_to(HERE.parent.parent)}` and commit the result",
                file=sys.stderr,
            )
            return 1
        print(f"generate_stubs: {len(files)} stubs match {PROTO_FILE}")
        return 0
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        (OUT_DIR / name).write_bytes(data)
    print(f"generate_stubs: wrote {', '.join(sorted(files))} to {OUT_DIR}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
