# ruff: noqa
# The harness as it ran (paths under /tmp/c73, the data of bench_checks.py --data-dir), kept verbatim.
import json
import sys

a = {r["key"]: r for r in json.load(open(sys.argv[1]))["rows"]}
for f in sys.argv[2:]:
    d = json.load(open(f)); b = {r["key"]: r for r in d["rows"]}
    keys = sorted(set(a) & set(b))
    ea = json.load(open(sys.argv[1]))["elapsed"]
    agree = {k: sum(a[x][k] == b[x][k] for x in keys) / len(keys) for k in ("lift", "shake", "fail")}
    print(f"{f}: n={len(keys)} speed {ea/d['elapsed']:.2f}x  agree lift {agree['lift']:.3f} shake {agree['shake']:.3f} fail {agree['fail']:.3f}  "
          f"lift {sum(a[x]['lift'] for x in keys)}->{sum(b[x]['lift'] for x in keys)} shake {sum(a[x]['shake'] for x in keys)}->{sum(b[x]['shake'] for x in keys)}")
