"""Write the direct recheck's verdicts into mutmut's .meta, for ``scripts/mutate.py --resume TREE --score-only``.

usage: python docs/mutation/recheck_setmeta.py TREE/mutants/bodystudio/PKG/MODULE.py.meta LOG...
Each LOG line is ``<mutant> killed|survived ...`` (docs/mutation/recheck_direct.py's output). A kill in any log
counts (a mutant killed by any test is killed); a kill mutmut itself saw is never downgraded.
"""
import json
import sys
from collections import Counter

meta_path = sys.argv[1]
meta = json.load(open(meta_path))
codes = meta["exit_code_by_key"]
verdict = {}
for log in sys.argv[2:]:
    for ln in open(log):
        p = ln.split()
        if len(p) >= 2 and p[1] in ("killed", "survived") and p[0] in codes:
            if p[1] == "killed" or verdict.get(p[0]) != 1:
                verdict[p[0]] = 1 if p[1] == "killed" else 0
for k, v in verdict.items():
    if codes[k] != 1:
        codes[k] = v
json.dump(meta, open(meta_path, "w"))
print(Counter(codes.values()))
