"""Structure prediction probe: fragment_structure at 300 random hit pixels (workers=1, CPU time against
core.irradiance at the same pixels), its H at P against the cached exact image, and its prediction 1 and 4
pixels to the right on the same plane. Usage: bench_structure_probe.py small 128"""
import sys
import time

import numpy as np

sys.path.insert(0, "benchmarks")
from bench_adaptive_oracle import reference

from hemisphere_local_pass.core import irradiance
from hemisphere_local_pass.core.fragment_structure import evaluate_structure, fragment_structure

key = sys.argv[1]; size=int(sys.argv[2])
scene, p, n, g, H = reference(key, size)
v = g >= 0
import hemisphere_local_pass.core.adaptive as ad

pl = np.where(v, ad._input_planes(scene)[np.maximum(g, 0)], -1)
same = np.ones_like(v[:, :-4])
for k in range(1, 5): same &= v[:, :-4] & (pl[:, k:pl.shape[1] - 4 + k] == pl[:, :-4])
ys, xs = np.nonzero(same)
rng = np.random.default_rng(1)
i = rng.choice(len(ys), 300, replace=False)
ys, xs = ys[i], xs[i]
t=time.process_time(); st = fragment_structure(scene, p[ys, xs], n[ys, xs]); t1=time.process_time()-t
t=time.process_time(); irradiance(scene, p[ys, xs], n[ys, xs], workers=1); t2=time.process_time()-t
print("extract", t1, "exact", t2)
amb = sum(s.ambiguous for s in st); print("ambiguous", amb)
from collections import Counter

print(Counter(r for s in st for r in s.reasons))
e0=[]; e1=[]; e4=[]
mean = H[v].mean()
for s, y, x in zip(st, ys, xs):
    e0.append(abs(s.H - H[y, x]).max()/max(H[y,x].max(),1e-300))
    pr = evaluate_structure(s, p[y, x+1:x+5])
    err = abs(pr - H[y, x+1:x+5]).max(axis=1)/mean
    e1.append(err[0]); e4.append(err[3])
e0=np.array(e0); e1=np.array(e1); e4=np.array(e4)
print("at P rel max", e0.max(), np.sort(e0)[-5:])
for q in (0.5,0.9,0.99,1): print(q, np.quantile(e1,q), np.quantile(e4,q))
print("frac step1 <1e-10", (e1<1e-10).mean(), "step4", (e4<1e-10).mean())
print("edges per structure", np.mean([s.n_edges for s in st]))
