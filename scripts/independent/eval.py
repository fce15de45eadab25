"""Score the diagnoses of run.sh: eval.py OUT_DIR (right: the expected cause
named and no other, final validation NRMSE <= 1.5x the noise floor)."""
import json, sys
out = sys.argv[1]
rows = []; times = {}
for l in open(f"{out}/r/times.txt"):
    n, rc, t = l.split(); times[n] = (int(rc), float(t))
ok = okc = 0
for n in sorted(times):
    meta = json.load(open(f"{out}/cases/{n}/meta.json"))
    rc, t = times[n]
    try:
        r = json.load(open(f"{out}/r/{n}.json"))
    except Exception:
        print(f"{n:22s} ERROR rc={rc}", open(f"{out}/r/{n}.txt").read()[-300:]); continue
    causes = r["causes"]; fin = r["final"]["nrmse"]; base = r["baseline"]["nrmse"]
    exp = meta["expected"]; fl = meta["floor"]
    cause_ok = (causes == [] if exp == "none" else (causes[:1] == [exp] and all(c == exp for c in causes)))
    ratio = fin / fl if fl else float('nan')
    right = cause_ok and (fl is None or ratio <= 1.5)
    ok += right; okc += cause_ok
    v = r["verdict"]["kind"]
    print(f"{n:22s} exp {exp:12s} got {','.join(causes) or 'none':28s} base {base:.4f} final {fin:.4f} floor {fl if fl is None else round(fl,4)} x{ratio:5.2f} {'OK ' if right else 'BAD'} {v:14s} {t:6.1f}s  {meta['excitation']} spp {meta['spp']:.0f}")
print(f"right {ok}/{len(times)}  cause-right {okc}/{len(times)}  median time {sorted(t for _,t in times.values())[len(times)//2]:.1f}s max {max(t for _,t in times.values()):.1f}s")
