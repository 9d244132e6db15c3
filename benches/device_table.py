"""The table of benches/device.sh: one line per relight report in the folder given, in the
order the script ran them (by file time), with where the wall time went and the fit's
shadow-ray throughput (rays re-traced in the phases over the seconds they took)."""
import json
import os
import sys

# The stages shown, in the report's names; the rest are summed into "other".
STAGES = ["bases: sky", "bases: surfaces", "bases: dirt, filter", "bases: bounce", "init: placement", "start", "optimise",
          "prune: terms", "prune: lights", "prune: merge", "prune: sun search", "prune: polish", "gamma"]

folder = sys.argv[1]
files = sorted((f for f in os.listdir(folder) if f.endswith(".json")), key=lambda f: os.path.getmtime(os.path.join(folder, f)))
print("| run | backend | total s | " + " | ".join(STAGES) + " | other | error | lights | phase rays | rays/s |")
print("|---|---|---:|" + "---:|" * (len(STAGES) + 5))
for f in files:
    r = json.load(open(os.path.join(folder, f)))
    st = {}
    for name, t in r["stage_times_s"]:
        st[name] = st.get(name, 0.0) + t
    shown = [st.get(s, 0.0) for s in STAGES]
    other = r["total_time_s"] - sum(shown)
    rays = sum(p.get("rays", 0) for p in r.get("phases", []))
    trace = sum(p.get("trace_s", 0.0) for p in r.get("phases", []))
    rate = f"{rays / trace / 1e9:.2f} G" if trace > 0 else ""
    cells = " | ".join(f"{t:.2f}" for t in shown)
    print(f"| {f[:-5]} | {r['backend']} | {r['total_time_s']:.2f} | {cells} | {other:.2f} | {r['rel_error_final']:.4f} | {len(r['lights'])} | {rays} | {rate} |")
