"""Run every benchmark module and write docs/BENCHMARKS.md.

A benchmark module is ``benchmarks/bench_*.py`` with ``run(quick: bool = False) -> str`` returning a
markdown section that starts with a ``## `` heading. Modules run in name order in this one process.
``--only NAME`` runs the modules whose name contains NAME and replaces just their sections in an
existing output file (each section carries the time and machine it was measured on); ``--quick`` asks
for smaller cases.
"""

from __future__ import annotations

import argparse
import datetime
import importlib
import os
import platform
import re
import sys
import traceback
from pathlib import Path

from bodystudio.fileio import atomic_write


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/BENCHMARKS.md"))
    parser.add_argument("--only", default="")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    here = Path(__file__).parent
    names = sorted(p.stem for p in here.glob("bench_*.py") if args.only in p.stem)
    sections = _existing_sections(args.out) if args.only else {}
    failed = []
    for name in names:
        print(f"benchmark {name} ...", flush=True)
        try:
            module = importlib.import_module(f"benchmarks.{name}")
            body = module.run(quick=args.quick).strip()
        except Exception:  # one broken benchmark must not hide the others' figures
            failed.append(name)
            body = f"## {name}\n\nFAILED:\n\n```\n{traceback.format_exc()}\n```"
        quick = " (quick)" if args.quick else ""
        sections[name] = f"<!-- bench:{name} -->\n{body}\n\n_Measured {_stamp()}{quick}._\n<!-- /bench:{name} -->"
    head = ("# Benchmarks\n\nWritten by `make bench` (`python -m benchmarks.run`). Medians of >= 5 runs; ratios are "
            "measured side by side in the same process. Each section says when and on what it was measured, with the "
            "machine's load average at the end of its run (other work on the 2 cores inflates wall times).\n")
    with atomic_write(args.out, "w") as f:
        f.write(head + "\n" + "\n\n".join(sections[k] for k in sorted(sections)) + "\n")
    print(f"wrote {args.out}")
    return 1 if failed else 0


def _stamp() -> str:
    now = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    return f"{now} on {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, load {load}"


def _existing_sections(path: Path) -> dict[str, str]:
    if not path.is_file():
        return {}
    text = path.read_text()
    return {m.group(1): m.group(0) for m in re.finditer(r"<!-- bench:(\w+) -->.*?<!-- /bench:\1 -->", text, re.S)}


if __name__ == "__main__":
    sys.exit(main())
