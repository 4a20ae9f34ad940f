"""Every command of the README, run in a fresh clone: each must exit with 0.

    python3 .ci/readme_check.py [--keep DIR]

Clones the repository's committed HEAD into a temporary folder and runs there, in order, every line
of the README's ```sh blocks (a line ending in a backslash continues on the next; comments and blank
lines are skipped), each in its own shell from the clone's root with the clone's ``.venv/bin`` first on
the PATH, as `. .venv/bin/activate` would put it, and every ```python block whole, by the clone's
``python``, where it stands among them. A block whose fence is preceded by a line starting with
``<!-- readme-check: skip`` is not run (the test suite's own command: ``.ci/run`` runs it). The first
block is the install and the main job, so the clone gets its own environment exactly as a new user's.
Exit 1 at the first command that fails, with its output.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SKIP = "<!-- readme-check: skip"


def commands(text: str) -> list[str]:
    """The README's runnable shell commands, in order (a Python block as one ``python -`` command)."""
    out, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        if lines[i].strip() == "```python" and not (i > 0 and lines[i - 1].strip().startswith(SKIP)):
            i += 1
            block = []
            while i < len(lines) and lines[i].strip() != "```":
                block.append(lines[i])
                i += 1
            out.append("python - <<'PYTHON'\n" + "\n".join(block) + "\nPYTHON")
        elif lines[i].strip() == "```sh":
            skip = i > 0 and lines[i - 1].strip().startswith(SKIP)
            i += 1
            block = []
            while i < len(lines) and lines[i].strip() != "```":
                block.append(lines[i])
                i += 1
            if not skip:
                cmd = ""
                for line in block:
                    cmd += line.strip() if cmd else line.rstrip()
                    if cmd.endswith("\\"):
                        cmd = cmd[:-1].rstrip() + " "
                        continue
                    if cmd.strip() and not cmd.lstrip().startswith("#"):
                        out.append(cmd.strip())
                    cmd = ""
        i += 1
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keep", metavar="DIR", help="clone into DIR (must not exist) and leave it there")
    args = ap.parse_args(argv)
    base = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="readme-"))
    clone = base / "clone" if not args.keep else base
    t0 = time.perf_counter()
    try:
        subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True)
        env = dict(
            os.environ,
            VIRTUAL_ENV=str(clone / ".venv"),
            PATH=f"{clone / '.venv' / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
        )
        env.pop("PYTHONPATH", None)
        cmds = commands((clone / "README.md").read_text())
        for k, cmd in enumerate(cmds, 1):
            t = time.perf_counter()
            r = subprocess.run(
                ["bash", "-c", cmd], cwd=clone, env=env, capture_output=True, text=True, stdin=subprocess.DEVNULL
            )
            dt = time.perf_counter() - t
            if r.returncode != 0:
                print(
                    f"README command {k} of {len(cmds)} exited with {r.returncode} after {dt:.0f} s: {cmd}\n"
                    f"--- stdout (end)\n{r.stdout[-3000:]}\n--- stderr (end)\n{r.stderr[-3000:]}",
                    file=sys.stderr,
                )
                return 1
            print(f"README command {k} of {len(cmds)} ran in {dt:5.1f} s: {cmd.splitlines()[0]}", flush=True)
        print(f"README commands: all {len(cmds)} exited with 0, {time.perf_counter() - t0:.0f} s in a fresh clone")
        return 0
    finally:
        if not args.keep:
            shutil.rmtree(base, ignore_errors=True)


if __name__ == "__main__":
    raise SystemExit(main())
