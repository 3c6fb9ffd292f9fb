"""The card of BALM's OS0-64-like unit used in docs/sequences.md ("Other sensors"): `sensor fit` of its first
frame finds 109 beams (each beam's points at two elevations: the frames are deskewed, their points do not
all leave one origin) and says so (split_beams); the close pairs (under 0.45 deg apart) merged, weighted by
their points, give the unit's 64. Run from the repository root: python docs/sequence_sensors/balm_card.py"""

import sys
import warnings

from slr_ray.sensorfit import fit_card, merge_split_beams
from slr_ray.sensors import BeamPattern, write_card

frame = sys.argv[1] if len(sys.argv) > 1 else "../shared/data/balm_os0_64/full20.pcd"
out = sys.argv[2] if len(sys.argv) > 2 else "balm_os0_64.json"
with warnings.catch_warnings(record=True) as said:
    warnings.simplefilter("always")
    fitted = fit_card(frame, name="balm_os0_64_fitted")
print(fitted.n_beams, "beams fitted;", fitted.meta["fit"], *[str(w.message) for w in said], sep="\n")
el = merge_split_beams(fitted, 0.45).elevation_deg  # the close pairs merged (slr-ray sensor fit --merge-split-beams)
card = BeamPattern(tuple(round(float(e), 4) for e in el), fitted.columns, name="balm_os0_64",
                   meta={"source": f"{fitted.meta['source']}; close pairs (< 0.45 deg) merged by "
                                   "docs/sequence_sensors/balm_card.py", "beams_from": "elevation bands"})
write_card(out, card)
print(card.n_beams, "beams after merging, columns", card.columns, "->", out)
