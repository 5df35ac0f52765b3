import pickle
from services.sim.scenes import hard_views, NO_MARKER
pickle.dump([v.rendered.image for v in hard_views(NO_MARKER, 200, seed=2025)], open("/tmp/i21b/nomarker.pkl0","wb"))
