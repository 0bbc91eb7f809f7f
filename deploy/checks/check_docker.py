#!/usr/bin/env python3
"""Offline lint of the Dockerfiles (no Docker engine needed).

  check_docker.py REPO docker/Dockerfile docker/Dockerfile.cuda

For each Dockerfile, with the repository root as the build context:
- every COPY/ADD source from the context exists and is not excluded by the
  Dockerfile's own .dockerignore (<Dockerfile>.dockerignore);
- every COPY --from names an earlier stage, and what it copies from the
  models directory is something setup-models.sh makes (as in ./models);
- every repository script a RUN calls (scripts/..., tools/...) exists, and
  the models come from scripts/setup-models.sh only (no pip, curl or wget of
  a second way to install);
- HUMEM_* variables given to setup-models.sh are read by it;
- the final stage runs as a non-root USER, declares the store as a VOLUME,
  EXPOSEs the ports of docker/humem.toml, and its CMD's --config file is
  COPY'd into the image.
"""

import fnmatch
import os
import re
import shlex
import sys
import tomllib

from common import Report


def instructions(path: str) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with line continuations joined and comments dropped."""
    out, current = [], ""
    with open(path, encoding="utf-8") as f:
        for line in f:
            stripped = line.strip()
            if not current and (not stripped or stripped.startswith("#")):
                continue
            if current and stripped.startswith("#"):
                continue
            if stripped.endswith("\\"):
                current += stripped[:-1] + " "
                continue
            current += stripped
            word, _, rest = current.partition(" ")
            out.append((word.upper(), rest.strip()))
            current = ""
    return out


def ignored(path: str, patterns: list[str]) -> bool:
    result = False
    for pattern in patterns:
        negate = pattern.startswith("!")
        pattern = pattern.lstrip("!").strip("/")
        parts = path.split("/")
        hit = any(fnmatch.fnmatch("/".join(parts[: i + 1]), pattern) for i in range(len(parts)))
        hit = hit or (pattern.startswith("**/") and fnmatch.fnmatch(parts[-1], pattern[3:]))
        if hit:
            result = not negate
    return result


def check(repo: str, dockerfile: str, r: Report) -> None:
    name = os.path.relpath(dockerfile, repo)
    ignore_file = dockerfile + ".dockerignore"
    patterns = []
    if r.check(os.path.isfile(ignore_file), f"{name}: has {os.path.basename(ignore_file)}"):
        with open(ignore_file, encoding="utf-8") as f:
            patterns = [l.strip() for l in f if l.strip() and not l.startswith("#")]
    setup_script = open(os.path.join(repo, "scripts/setup-models.sh"), encoding="utf-8").read()
    stages, final, models_dir = [], {}, None
    args = {}
    for instruction, rest in instructions(dockerfile):
        if instruction == "ARG":
            key, _, value = rest.partition("=")
            args[key] = value
        elif instruction == "FROM":
            words = rest.split()
            stages.append(words[2] if len(words) > 2 and words[1].upper() == "AS" else str(len(stages)))
            image = re.sub(r"\$\{?(\w+)\}?", lambda m: args.get(m.group(1), m.group(0)), words[0])
            r.check(":" in image and not image.endswith(":latest"), f"{name}: FROM {image} is pinned by tag")
            final = {"user": None, "volumes": [], "expose": [], "copied": [], "cmd": None}
        elif instruction in ("COPY", "ADD"):
            words = shlex.split(rest)
            flags = [w for w in words if w.startswith("--")]
            paths = [w for w in words if not w.startswith("--")]
            sources, dest = paths[:-1], paths[-1]
            source_stage = next((f.split("=", 1)[1] for f in flags if f.startswith("--from=")), None)
            if source_stage:
                r.check(source_stage in stages[:-1], f"{name}: COPY --from={source_stage} names an earlier stage")
                for source in sources:
                    # What setup-models.sh put in its DIR is what it puts in models/ here.
                    if models_dir and source.startswith(models_dir + "/") and os.path.isdir(os.path.join(repo, "models")):
                        local = os.path.join("models", source[len(models_dir) + 1:])
                        r.check(os.path.exists(os.path.join(repo, local)),
                                f"{name}: COPY --from={source_stage} {source}: setup-models.sh makes it ({local})")
            else:
                for source in sources:
                    found = os.path.exists(os.path.join(repo, source)) if source != "." else True
                    r.check(found, f"{name}: COPY source {source} exists in the context")
                    if source != ".":
                        r.check(not ignored(source, patterns), f"{name}: COPY source {source} is not .dockerignored")
                final["copied"].append(dest)
        elif instruction == "RUN":
            for script in re.findall(r"(?<![\w/])((?:scripts|tools)/[\w./-]+)", rest):
                r.check(os.path.isfile(os.path.join(repo, script)), f"{name}: RUN calls {script}, which exists")
            for tool in ("pip ", "pip3 ", "curl ", "wget ", "onnxruntime"):
                if tool in rest and "setup-models.sh" not in rest:
                    r.fail(f"{name}: RUN installs with {tool.strip()} instead of scripts/setup-models.sh: {rest[:80]}")
            if "setup-models.sh" in rest:
                m = re.search(r"setup-models\.sh\s+(\S+)", rest)
                models_dir = m.group(1).rstrip("/") if m else None
                for var in re.findall(r"\b(HUMEM_\w+)=", rest):
                    r.check(var in setup_script,
                            f"{name}: scripts/setup-models.sh reads the {var} it is given")
        elif instruction == "USER":
            final["user"] = rest.split(":")[0]
        elif instruction == "VOLUME":
            final["volumes"] += shlex.split(rest.strip("[]").replace(",", " "))
        elif instruction == "EXPOSE":
            final["expose"] += [int(p.split("/")[0]) for p in rest.split()]
        elif instruction == "CMD":
            final["cmd"] = shlex.split(rest.strip("[]").replace(",", " "))
    r.check(any("setup-models.sh" in rest for i, rest in instructions(dockerfile) if i == "RUN"),
            f"{name}: models come from scripts/setup-models.sh")
    r.check(final["user"] not in (None, "root", "0"), f"{name}: final stage runs as USER {final['user']}")
    config_path = final["cmd"][final["cmd"].index("--config") + 1] if final["cmd"] and "--config" in final["cmd"] else None
    r.check(config_path in final["copied"], f"{name}: CMD --config {config_path} is COPY'd into the image")
    with open(os.path.join(repo, "docker/humem.toml"), "rb") as f:
        config = tomllib.load(f)
    r.check(config["store"]["data_dir"] in final["volumes"], f"{name}: VOLUME {final['volumes']} holds store.data_dir")
    ports = {int(config[s]["listen"].rsplit(":", 1)[1]) for s in ("server", "metrics")}
    r.check(ports <= set(final["expose"]), f"{name}: EXPOSE {final['expose']} covers {sorted(ports)}")


def main(repo: str, dockerfiles: list[str]) -> None:
    r = Report("docker")
    for dockerfile in dockerfiles:
        check(repo, os.path.join(repo, dockerfile), r)
    r.finish()


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
