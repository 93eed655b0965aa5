"""Run every benchmark module and write docs/BENCHMARKS.md.

A benchmark module is ``benchmarks/bench_*.py`` with ``run(quick: bool = False) -> str`` returning a
markdown section that starts with a ``## `` heading. Modules run in name order in this one process.
``--only NAME`` runs the modules whose name contains NAME; ``--quick`` asks for smaller cases.
"""

from __future__ import annotations

import argparse
import datetime
import importlib
import os
import platform
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
    sections, failed = [], []
    for name in names:
        print(f"benchmark {name} ...", flush=True)
        try:
            module = importlib.import_module(f"benchmarks.{name}")
            sections.append(module.run(quick=args.quick).strip())
        except Exception:  # one broken benchmark must not hide the others' figures
            failed.append(name)
            sections.append(f"## {name}\n\nFAILED:\n\n```\n{traceback.format_exc()}\n```")
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    head = (f"# Benchmarks\n\nWritten by `make bench` on {stamp}: {platform.processor() or platform.machine()}, "
            f"{os.cpu_count()} cores, Python {platform.python_version()}. Medians of >= 5 runs; ratios are "
            f"measured side by side in the same process.\n")
    with atomic_write(args.out, "w") as f:
        f.write(head + "\n" + "\n\n".join(sections) + "\n")
    print(f"wrote {args.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
