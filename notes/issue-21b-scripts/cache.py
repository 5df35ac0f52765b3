import sys, pickle, time
import numpy as np
from services.sim.scenes import hard_views
cond, seed, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
t=time.time()
out=[]
for v in hard_views(cond, n, seed=seed):
    r=v.rendered
    if r.marker_visible and r.vertices_px is not None:
        out.append((r.image, r.vertices_px))
pickle.dump(out, open(f"/tmp/i21b/{cond[:6].replace(' ','_')}_{seed}.pkl","wb"))
print(cond, seed, len(out), time.time()-t)
