"""The MRCLAM table of docs/RESULTS.md from the benchmark's results.json and the motion-gains rows.

    python docs/scripts/mrclam_table.py [RESULTS_JSON] [GAINS_ROWS_JSON]

Defaults: docs/measurements/mrclam_600s_known.json (online-em-slam-mrclam-benchmark
--seconds 600 --seeds 0 1 --ids known --methods online_em ekf_slam fastslam2 batch) and
docs/measurements/mrclam_600s_known_motion_gains.json (online EM with motion_gains learned,
seeds 0 and 1: rows bag, variant, method, seed, matched, spurious, shape, rmse, trajectory).
"""
import sys
import json, numpy as np, collections
R = json.load(open(sys.argv[1] if len(sys.argv) > 1 else 'docs/measurements/mrclam_600s_known.json'))['runs']
G = json.load(open(sys.argv[2] if len(sys.argv) > 2 else 'docs/measurements/mrclam_600s_known_motion_gains.json'))
cells = collections.defaultdict(list)
for r in R:
    if r['kind'] == 'convert' or r['status'] not in ('ok', 'reused') or r['landmark_shape'] is None: continue
    m = r['method'] + ('_L' if r['noise'] == 'learned' else '')
    cells[(r['dataset'], r['robot'], m)].append((r['landmark_shape'], r['matched'], r['spurious'], r['trajectory_rmse']))
for bag, variant, method, seed, matched, spur, shape, rmse, traj in G:
    d, rb = int(bag[1]), int(bag[3])
    cells[(d, rb, 'online_em_gains')].append((shape, matched, spur, traj))
def cell(v):
    a = np.array(v, dtype=float)
    se = a[:,0].std(ddof=1)/np.sqrt(len(a)) if len(a) > 1 else 0.0
    return a[:,0].mean(), se, int(a[:,1].min()), int(a[:,2].max()), a[:,3].mean()
def best(d, r, m):
    c = [(cell(cells[(d,r,k)]), tag) for k, tag in ((m,'P'),(m+'_L','L')) if cells.get((d,r,k))]
    c.sort(key=lambda x: (-x[0][2], x[0][0]))
    return c[0]
rows, summ = [], collections.defaultdict(list)
print("| run | online EM, no calibration | online EM, `config/mrclam.yaml` | EKF-SLAM | FastSLAM 2.0 | GTSAM batch |")
print("|---|---|---|---|---|---|")
wins = wins_g = 0
for d in (1, 9):
    for r in range(1, 6):
        em, emg = cell(cells[(d,r,'online_em')]), cell(cells[(d,r,'online_em_gains')])
        ekf, ekft = best(d, r, 'ekf_slam'); fs, fst = best(d, r, 'fastslam2'); bt, btt = best(d, r, 'batch')
        f = lambda c: f"{c[0]:.3f}" + (f" ± {c[1]:.3f}" if c[1] else "") + f" · {c[2]}/15 · {c[3]}"
        print(f"| D{d} R{r} | {f(em)} | {f(emg)} | {f(ekf)} ({ekft}) | {f(fs)} ({fst}) | {f(bt)} ({btt}) |")
        better = min(ekf[0], fs[0])
        wins += em[0] <= better; wins_g += emg[0] <= better
        for k, c in (('em', em), ('emg', emg), ('ekf', ekf), ('fs', fs), ('batch', bt), ('better', (better,0,0,0,0))):
            summ[k].append(c)
print()
for k, v in summ.items():
    a = np.array([x[0] for x in v]); print(k, "mean shape %.3f" % a.mean(), "within-1m sum", sum(x[2] for x in v), "spurious sum", sum(x[3] for x in v), "traj %.3f" % np.mean([x[4] for x in v]))
print("online EM <= better of EKF/FastSLAM:", wins, "/10; with gains:", wins_g, "/10")
b = np.array([x[0] for x in summ['batch']])
print("ratio to batch (mean shape / mean batch): em %.2f emg %.2f" % (np.mean([x[0] for x in summ['em']])/b.mean(), np.mean([x[0] for x in summ['emg']])/b.mean()))
