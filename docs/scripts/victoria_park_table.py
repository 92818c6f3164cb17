"""Victoria Park seeds (docs/measurements/victoria_park_learning.md): trajectory error vs GPS of
PREFIX_{hand,final}_SEED run directories, with and without the GPS glitches (fixes more than
20 m from both neighbouring fixes' midpoint: a property of the GPS alone)."""
import json, sys, numpy as np
def load(p):
    a = np.loadtxt(p); return a[:, 0], a[:, 1:3]
def errors(d):
    tg, g = load(f"{d}/ground_truth.tum"); te, e = load(f"{d}/sensor_trajectory.tum")
    ok = (tg >= te[0]) & (tg <= te[-1]); tg, g = tg[ok], g[ok]
    est = np.column_stack([np.interp(tg, te, e[:, 0]), np.interp(tg, te, e[:, 1])])
    err = np.linalg.norm(est - g, axis=1)
    mid = 0.5 * (g[:-2] + g[2:]); glitch = np.zeros(len(g), bool)
    glitch[1:-1] = np.linalg.norm(g[1:-1] - mid, axis=1) > 20.0
    return err, glitch
PREFIX = sys.argv[1] if len(sys.argv) > 1 else "/tmp/vps"
rows = {}
for c in ("hand", "final"):
    for s in range(5):
        d = f"{PREFIX}_{c}_{s}"
        try: m = json.load(open(f"{d}/metrics.json"))
        except FileNotFoundError: continue
        err, gl = errors(d)
        rows.setdefault(c, []).append((s, m["trajectory"]["rmse"], m["trajectory"]["median"], np.sqrt(np.mean(err[~gl]**2)), int(gl.sum()), m["n_landmarks"], m["timing"].get("real_time_factor", float("nan")), m.get("noise_learned")))
for c, r in rows.items():
    for s, rmse, med, clean, ng, nl, rtf, learned in r:
        extra = "" if not learned or not learned.get("enabled") else " sr %.3f sb %.2fdeg dof %.2f scale %.3f" % (learned["sigma_range"], np.degrees(learned["sigma_bearing"]), learned.get("dof", float("nan")), learned["motion_scale"])
        print(f"{c} seed {s}: rmse {rmse:.3f} median {med:.3f} rmse-no-glitch {clean:.3f} ({ng} glitch fixes) landmarks {nl} rtf {rtf}{extra}")
    a = np.array([x[1:4] for x in r]); n = len(a)
    print(c, "mean rmse %.3f ± %.3f, median %.3f ± %.3f, no-glitch %.3f ± %.3f (n=%d)" % (a[:,0].mean(), a[:,0].std(ddof=1)/np.sqrt(n), a[:,1].mean(), a[:,1].std(ddof=1)/np.sqrt(n), a[:,2].mean(), a[:,2].std(ddof=1)/np.sqrt(n), n))
if len(rows.get("hand", [])) == len(rows.get("final", [])) and rows.get("hand"):
    d = np.array([f[1:4] for f in rows["final"]]) - np.array([h[1:4] for h in rows["hand"]]); n = len(d)
    print("paired learned - hand: rmse %.3f ± %.3f, median %.3f ± %.3f, no-glitch %.3f ± %.3f" % (d[:,0].mean(), d[:,0].std(ddof=1)/np.sqrt(n), d[:,1].mean(), d[:,1].std(ddof=1)/np.sqrt(n), d[:,2].mean(), d[:,2].std(ddof=1)/np.sqrt(n)))
