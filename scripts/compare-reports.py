#!/usr/bin/env python3
"""scripts/compare-reports.py BASE_DIR NEW_DIR: two report folders of one scenario agree to the
last digit, except wall-clock measurements (timings, real-time factor). Exit 1 on a difference."""
import json, sys, re
TIMING = re.compile(r"(_us|wall|real_time|rtf|elapsed|_s_wall|settle_wall)", re.I)
def flat(x, p=""):
    if isinstance(x, dict):
        for k, v in x.items(): yield from flat(v, f"{p}.{k}")
    elif isinstance(x, list):
        for i, v in enumerate(x): yield from flat(v, f"{p}[{i}]")
    else: yield p, x
a, b = sys.argv[1], sys.argv[2]
A = dict(flat(json.load(open(f"{a}/metrics.json")))); B = dict(flat(json.load(open(f"{b}/metrics.json"))))
bad = 0
for k in sorted(set(A) | set(B)):
    if TIMING.search(k) or k in (".mode",): continue
    if A.get(k, "<missing>") != B.get(k, "<missing>"):
        bad += 1; print(f"DIFF {k}: {A.get(k, '<missing>')} -> {B.get(k, '<missing>')}")
for f in ("timeseries.csv", "torques.csv"):
    if open(f"{a}/{f}").read() != open(f"{b}/{f}").read():
        bad += 1; print(f"DIFF {f} differs")
print(f"{'IDENTICAL' if not bad else 'DIFFERENT'}: {len(A)} metric fields compared, {bad} differences (timings ignored); CSVs {'same' if not bad else 'checked'}")
sys.exit(1 if bad else 0)
