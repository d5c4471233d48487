"""Run every benchmark and rewrite its table in BENCHMARKS.md.

    python -m benchmarks [--only transport,first_call] [--dry-run]
    python benchmarks/run_all.py [same options]

(from the repository root). Each benchmark script of ``BENCHMARKS`` runs in its own
Python process (as ``python benchmarks/SCRIPT ARGS``; the scripts start further processes
of their own, so peak memory and compilation are per case). What a script prints on
stdout, a ``Machine: ...`` line and a Markdown table, replaces the block between the
markers ``<!-- benchmark:NAME -->`` and ``<!-- /benchmark:NAME -->`` of BENCHMARKS.md,
under a line with the date, the commit and the command. The rest of the file is kept.
A script that fails leaves its block as it was, and the run exits with code 1.

Timings are only worth keeping from a quiet machine: nothing else running (the
transport case alone takes minutes of both cores). ``--dry-run`` prints the new blocks
instead of writing them.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from datetime import date
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
BENCHMARKS_FILE = ROOT / "BENCHMARKS.md"

#: Block name in BENCHMARKS.md -> the script in benchmarks/ and its arguments.
BENCHMARKS = {
    "transport": ["transport.py", "--rays", "1024"],
    "first_call": ["first_call.py"],
    "tracks": ["tracks.py"],
    "generator": ["generator.py"],
}


def markers(name: str) -> tuple[str, str]:
    """The opening and closing markers of block ``name`` in BENCHMARKS.md."""
    return f"<!-- benchmark:{name} -->", f"<!-- /benchmark:{name} -->"


def commit() -> str:
    """The short hash of the checked-out commit, with ``+changes`` when the working tree
    differs from it; ``unknown`` outside git."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, check=True,
                              capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=ROOT, check=True, capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+changes" if dirty.strip() else "")


def run_benchmark(name: str) -> str:
    """Run benchmark ``name`` and return its Markdown block (without markers). Its
    stderr goes to the terminal; its stdout must hold a ``Machine:`` line and a table."""
    script, *arguments = BENCHMARKS[name]
    command = [sys.executable, str(HERE / script), *arguments]
    print(f"{name}: {' '.join(['python', f'benchmarks/{script}', *arguments])}",
          file=sys.stderr, flush=True)
    began = time.perf_counter()
    out = subprocess.run(command, cwd=ROOT, check=True, stdout=subprocess.PIPE,
                         text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"}).stdout
    print(f"{name}: done in {time.perf_counter() - began:.0f} s", file=sys.stderr, flush=True)
    lines = [line.rstrip() for line in out.strip().splitlines()]
    if not any(line.startswith("Machine:") for line in lines) or not any(
            line.startswith("|") for line in lines):
        raise ValueError(f"{script} printed no 'Machine:' line and table:\n{out}")
    stamp = (f"Measured {date.today().isoformat()} on commit {commit()} by"
             f" `python benchmarks/{' '.join([script, *arguments])}`"
             " (`python -m benchmarks`).")
    return "\n".join([stamp, "", *lines])


def replace_block(text: str, name: str, block: str) -> str:
    """``text`` with the block of ``name`` between its markers replaced by ``block``."""
    start, end = markers(name)
    pattern = re.compile(re.escape(start) + r"\n.*?" + re.escape(end), re.DOTALL)
    if not pattern.search(text):
        raise ValueError(f"{BENCHMARKS_FILE.name}: no block {start} ... {end}")
    return pattern.sub(lambda _: f"{start}\n{block}\n{end}", text, count=1)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default=",".join(BENCHMARKS),
                        help="comma-separated benchmarks to run (default: all:"
                             " %(default)s)")
    parser.add_argument("--dry-run", action="store_true",
                        help="print the new blocks instead of rewriting BENCHMARKS.md")
    parser.add_argument("--file", type=Path, default=BENCHMARKS_FILE,
                        help="the file whose blocks are rewritten (default BENCHMARKS.md)")
    args = parser.parse_args()
    names = [name for name in args.only.split(",") if name]
    unknown = [name for name in names if name not in BENCHMARKS]
    if unknown:
        parser.error(f"--only: unknown {', '.join(unknown)} (choose from"
                     f" {', '.join(BENCHMARKS)})")
    text = args.file.read_text()
    for name in names:  # check every marker before minutes of benchmarks
        replace_block(text, name, "")
    failed = []
    for name in names:
        try:
            block = run_benchmark(name)
        except (subprocess.CalledProcessError, ValueError) as error:
            print(f"{name}: failed ({error}); its block is left as it was", file=sys.stderr)
            failed.append(name)
            continue
        if args.dry_run:
            print(f"{markers(name)[0]}\n{block}\n{markers(name)[1]}\n")
            continue
        text = replace_block(args.file.read_text(), name, block)
        partial = args.file.with_name(args.file.name + ".partial")
        partial.write_text(text)
        partial.replace(args.file)  # written whole, after each benchmark
        print(f"{name}: table written to {args.file}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
