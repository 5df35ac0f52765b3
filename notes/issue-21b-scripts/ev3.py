import sys, pickle, glob
import numpy as np
from services.vertex_extractor.extractor import RhombusExtractor, ExtractorParams
cc = sys.argv[1] == "1"
import services.vertex_extractor.extractor as X; X.CROSS_CHECK = cc; ex = RhombusExtractor()
for f in sorted(glob.glob("/tmp/i21b/*.pkl")):
    data = pickle.load(open(f, "rb"))
    found = wrong = 0; errs = []; nees = []
    for img, truth in data:
        ex.reset(); d = ex.extract(img)
        if not d.found: continue
        found += 1
        e = np.linalg.norm(d.vertices_px - truth, axis=1); errs.append(e); wrong += e.max() > 2
        r = d.vertices_px - truth
        nees += [float(r[k] @ np.linalg.solve(d.vertices_cov_px2[k], r[k])) for k in range(4)]
    e = np.concatenate(errs)
    print(f"| {f.split('/')[-1][:-4]:16s} | {found:3d}/{len(data)} | {np.median(e):.3f} | {np.percentile(e,95):.3f} | {wrong} | {np.mean(nees):.2f} |")
imgs = pickle.load(open("/tmp/i21b/nomarker.pkl0","rb"))
print("no marker false detections", sum(ex.extract(i).found for i in imgs if not ex.reset()), "/", len(imgs))
