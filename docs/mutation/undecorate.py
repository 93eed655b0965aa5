"""Move every @X.command("name") decorator of a CLI module to a call at the end (mutmut mutates no decorated function)."""
import re
import sys

path = sys.argv[1]
lines = open(path).read().split("\n")
out, calls, pending = [], [], None
for ln in lines:
    m = re.match(r'^@([\w.]+)\.command\((.*)\)$', ln)
    if m:
        pending = (m.group(1), m.group(2))
        continue
    if pending and ln.startswith("def "):
        name = re.match(r"def (\w+)", ln).group(1)
        calls.append(f"{pending[0]}.command({pending[1]})({name})")
        pending = None
    out.append(ln)
text = "\n".join(out).rstrip("\n") + "\n\n\n" + "\n".join(calls) + "\n"
open(path, "w").write(text)
print(path, calls)
