"""The ACFR ute's motion calibration fitted to GPS: speed gain s, steering gain g, steering
offset d, by least squares of the laser point's dead-reckoned track against the GPS fixes over
windows of W seconds (each window's initial pose free). Standard errors assume independent
residuals (optimistic).

    python docs/scripts/ute_calibration_gps.py car_park 10      # or victoria_park
"""
import sys
import numpy as np
from scipy.optimize import least_squares
from online_em_slam.datasets.kth.datasets import load_car_park, load_victoria_park, VEHICLE

L, H, A, B = VEHICLE.wheelbase, VEHICLE.encoder_offset, VEHICLE.sensor_x, VEHICLE.sensor_y

def integrate(t, ve, al, pose0, s, g, d):
    v = s * ve; a = g * al + d
    ta = np.tan(a); vc = v / (1 - ta * H / L)
    dt = np.diff(t, append=t[-1])
    w = vc * ta / L
    th = pose0[2] + np.concatenate([[0], np.cumsum((w * dt)[:-1])])
    x = pose0[0] + np.concatenate([[0], np.cumsum((vc * np.cos(th) * dt)[:-1])])
    y = pose0[1] + np.concatenate([[0], np.cumsum((vc * np.sin(th) * dt)[:-1])])
    return x, y, th

def laser(x, y, th):
    return x + A * np.cos(th) - B * np.sin(th), y + A * np.sin(th) + B * np.cos(th)

def windows(odo, gps, W, min_speed=0.5):
    out = []
    t0 = max(odo.times[0], gps.times[0]); t1 = min(odo.times[-1], gps.times[-1])
    k = t0
    while k + W <= t1:
        m = (odo.times >= k) & (odo.times <= k + W)
        g = (gps.times >= k) & (gps.times <= k + W)
        if g.sum() >= 5 and np.mean(np.abs(odo.speed[m])) > min_speed:
            out.append((odo.times[m], odo.speed[m], odo.steering[m], gps.times[g], gps.x[g], gps.y[g]))
        k += W
    return out

def residuals(p, wins, free):
    params = dict(s=1.0, g=1.0, d=0.0)
    for i, name in enumerate(free):
        params[name] = p[i]
    res = []
    for j, (t, ve, al, gt, gx, gy) in enumerate(wins):
        pose0 = p[len(free) + 3 * j: len(free) + 3 * j + 3]
        x, y, th = integrate(t, ve, al, pose0, **params)
        lx, ly = laser(x, y, th)
        res.append(np.interp(gt, t, lx) - gx); res.append(np.interp(gt, t, ly) - gy)
    return np.concatenate(res)

def init_pose(w):
    t, ve, al, gt, gx, gy = w
    th = np.arctan2(gy[min(4, len(gy)-1)] - gy[0], gx[min(4, len(gx)-1)] - gx[0])
    return [gx[0] - A * np.cos(th) + B * np.sin(th), gy[0] - A * np.sin(th) - B * np.cos(th), th]

def fit(wins, free):
    p0 = [1.0 if n != "d" else 0.0 for n in free] + sum((init_pose(w) for w in wins), [])
    r = least_squares(residuals, p0, args=(wins, free), x_scale='jac')
    J = r.jac; n = len(r.fun); dof = n - len(p0)
    s2 = (r.fun ** 2).sum() / dof
    cov = np.linalg.pinv(J.T @ J) * s2
    se = np.sqrt(np.diag(cov))[:len(free)]
    return r.x[:len(free)], se, np.sqrt(s2), n

if __name__ == "__main__":
    name, W = sys.argv[1], float(sys.argv[2])
    if name == "car_park":
        d = load_car_park(); odo, gps = d.odometry, d.gps
    else:
        d = load_victoria_park(); odo, gps = d.dr, d.gps
    wins = windows(odo, gps, W)
    print(name, "windows", len(wins))
    for free in (("s", "g"), ("s", "g", "d"), ("s", "d")):
        x, se, rms, n = fit(wins, free)
        print(free, " ".join(f"{v:.4f}±{e:.4f}" for v, e in zip(x, se)), f"rms {rms:.3f} m n {n}")
