"""Score a named subset of a kept mutmut tree's mutants into docs/mutation/results.json under a key of one's own.

usage (from the repository root): python docs/mutation/score_subset.py TREE MODULE KEY NAMES.txt TESTS RERUN
    [--functions f ...] [--history-before SCORE LABEL]
TREE is a tree kept by ``scripts/mutate.py --keep`` whose .meta holds the verdicts (mutmut's, then the direct
recheck's through recheck_setmeta.py); NAMES.txt the mutants to count (e.g. those of the lines a change added);
TESTS comma-separated test files; RERUN a sentence on how the verdicts were obtained. Killed = exit code 1 or a
crash signal (as scripts/mutate.py counts them); anything else is a survivor, listed with its diff. The rendered
block of docs/MUTATION.md is rewritten (``scripts/mutate.write_report``). ``scripts/mutate.py --score-only`` writes
under "MODULE (functions)" and would overwrite another run's entry: this writes only KEY.
"""
import argparse
import datetime as dt
import difflib
import json
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
import mutate  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("tree")
ap.add_argument("module")
ap.add_argument("key")
ap.add_argument("names")
ap.add_argument("tests")
ap.add_argument("rerun")
ap.add_argument("--functions", nargs="+", default=[])
ap.add_argument("--history-before", nargs=2, metavar=("SCORE", "LABEL"))
args = ap.parse_args()

src = (Path(args.tree) / "mutants" / args.module).read_text()
codes = json.loads((Path(args.tree) / "mutants" / (args.module + ".meta")).read_text())["exit_code_by_key"]
names = [ln.strip() for ln in open(args.names) if ln.strip()]
missing = [n for n in names if n not in codes]
if missing:
    sys.exit(f"score_subset: {len(missing)} names not in the tree's .meta (first {missing[0]}); check TREE / MODULE")


def body(fn):
    """The lines of mutmut's function (or method: indented in its class) ``fn``, up to the next line as shallow."""
    m = re.search(rf"^( *)def {re.escape(fn)}\(", src, re.M)
    lines = src[m.start():].splitlines()
    indent = len(m.group(1))
    out = [lines[0]]
    for ln in lines[1:]:
        if ln.strip() and len(ln) - len(ln.lstrip()) <= indent and not ln.lstrip().startswith(")"):
            break
        out.append(ln)
    return out


KILLED = {1, -6, -7, -8, -11, 134, 135, 136, 139}  # a failing test, or SIGABRT / SIGBUS / SIGFPE / SIGSEGV
counts: dict[str, int] = {}
survivors = []
for n in names:
    c = codes[n]
    status = "killed" if c in KILLED else ("survived" if c == 0 else "not checked" if c is None else f"exit {c}")
    counts[status] = counts.get(status, 0) + 1
    if status != "killed":
        short = n.split(".x", 1)[1]
        short = "x" + short
        orig = short.rsplit("__mutmut", 1)[0] + "__mutmut_orig"
        diff = [ln for ln in difflib.unified_diff(body(orig), body(short), lineterm="", n=0)
                if ln[:1] in "+-" and not ln.startswith(("---", "+++")) and " def " not in f" {ln[1:4]} "
                and not re.match(r"[+-]def x", ln)]
        shown = short[2:] if short.startswith("x_") else short[1:].strip("\u01c1").replace("\u01c1", ".")
        survivors.append({"mutant": shown, "status": status, "diff": diff})
killed = counts.get("killed", 0)
results = json.loads(mutate.RESULTS.read_text())
history = results.get(args.key, {}).get("history", [])
if args.history_before and not history:
    history.append({"date": dt.date.today().isoformat(), "commit": args.history_before[1],
                    "score": float(args.history_before[0])})
score = round(killed / len(names), 4)
history.append({"date": dt.date.today().isoformat(), "commit": mutate.git_commit() + " (direct recheck)",
                "score": score})
results[args.key] = {"module": args.module, "commit": mutate.git_commit(), "tests": args.tests.split(","),
                     "counts": counts, "killed": killed, "total": len(names), "score": score, "wall_s": 0.0,
                     "timed_out": False, "survivors": survivors, "functions": args.functions, "history": history,
                     "rerun": args.rerun}
mutate.write_report(results)
print(f"{args.key}: {score:.1%} ({killed} / {len(names)}) {counts}")
