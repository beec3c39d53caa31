"""Perception as the loop does it, against the simulated world's truth: rendered frame ->
segmentation -> regions mapped at each part's height -> the model registered on them."""

from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import Polygon

from cell.runtime.matching import Region, locate
from cell.runtime.session import displaced
from cell.scene import load_assembly

ASSEMBLIES = Path(str(resources.files("cell") / "data" / "assemblies"))


# drive_unit 3, 5, 8: a washer touching the pulley, split off it by the neck search with its hole
# filled, and its hole then grazed by the jagged split line (both mended; the washer was not found)
@pytest.mark.parametrize("name,seed", [("default", 0), ("default", 7), ("drive_unit", 1), ("drive_unit", 3),
                                       ("drive_unit", 5), ("drive_unit", 8)])
def test_every_part_is_located_where_it_really_lies(name, seed):
    from calibration import load_calibration
    from cell.vision import SegmentParams, SimCamera, SimCameraOptions, segment_frame, segment_to_mm

    cal = load_calibration()
    assembly = load_assembly(ASSEMBLIES / f"{name}.json")
    truth = {p.id: p for p in displaced(assembly, 2.0, seed)}
    frame = SimCamera(cal, SimCameraOptions(seed=seed)).render(list(truth.values()))
    segments = segment_frame(frame, SegmentParams.for_calibration(cal))

    def region(i, s):
        def at(z_top, z_bottom):
            poly = Polygon(*segment_to_mm(s, cal, z_top, z_bottom, frame))
            return poly if poly.is_valid else poly.buffer(0)
        return Region(i, at, s.merged, s.cut_off)

    found, _ = locate(list(assembly.parts), [region(i, s) for i, s in enumerate(segments)])
    assert set(found) == set(truth)
    for part in assembly.parts:
        seen = found[part.id].apply(part)
        err = np.hypot(*np.subtract(seen.polygon.centroid.coords[0], truth[part.id].polygon.centroid.coords[0]))
        assert err < 1.0, (part.id, err, found[part.id])
        assert seen.polygon.symmetric_difference(truth[part.id].polygon).area < 0.1 * part.polygon.area, part.id
