"""Cost of the rounding term in the fit: fit_ramps on 1024^2 Roman-table ramps with a
per-pixel read-noise map, with and without resultant_noise, alternating pairs.

    python tests/tools/resultant_noise_cost.py
"""
import time, numpy as np, sys, os
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
import ramp_sim
from noise.adc import averaging_noise
from scenesim.rampfit import fit_ramps
rng = np.random.default_rng(1)
times = ramp_sim.roman_times()
shape = (1024, 1024)
res = ramp_sim.simulate(rng, 1.0, times, 6.0, shape).astype(np.float32)
rn = np.full(shape, 6.5)                      # a per-pixel map, as scenesim fit passes
q = averaging_noise(2.0, [len(t) for t in times])
for thr in (None, 5.0):
    ratios = []
    for rep in range(3):
        out = []
        for qq in (0.0, q) if rep % 2 == 0 else (q, 0.0):
            t0 = time.perf_counter()
            fit_ramps(res, times, read_noise=rn, resultant_noise=qq, jump_threshold=thr, threads=2)
            out.append((np.ndim(qq), time.perf_counter() - t0))
        d = dict(out)
        ratios.append(d[1] / d[0])
        print(f"jumps={thr} rep {rep}: without {d[0]:.3f} s, with {d[1]:.3f} s, ratio {d[1]/d[0]:.3f}", flush=True)
    print(f"jumps={thr}: median ratio {np.median(ratios):.3f} (range {min(ratios):.3f}-{max(ratios):.3f}); load {os.getloadavg()}")
