"""The paper's numbers, named once.

Every default of slr_ray that comes from the paper (Simulated LiDAR
Repositioning, the method this package implements) is defined here, so a
reader can see which values are the paper's and which are ours, and a change
of one is a change in one place. Values are plain numbers (degrees, metres,
point counts).
"""

from __future__ import annotations

import math

__all__ = [
    "SECONDARY_RESOLUTION", "SYNS_RESOLUTION", "PRIMARY_RESOLUTION", "PRIMARY_RESOLUTION_FINE",
    "SCANNER_HEIGHT", "SIMILARITY_THRESHOLD", "NEAR_DISTANCE", "MIN_GROUND_POINTS", "CELL_SIZE",
    "GROUND_COUNT_RADIUS", "GROUND_HEIGHT_RADIUS", "DENSE_SPACING", "SWEEP_HEIGHTS",
    "Q1_SCENES", "Q2_SCENES", "DISTANCE_BANDS",
]

#: Angular resolution of the secondary (true and SLR) scans, degrees (the
#: SYNS dataset's sparser scans).
SECONDARY_RESOLUTION = 0.144
#: Angular resolution of the dense SYNS scans, degrees.
SYNS_RESOLUTION = 0.036
#: Primary scans of the validation, questions 1 and 2 (degrees).
PRIMARY_RESOLUTION = 0.0144
#: Primary scans of question 3 (degrees).
PRIMARY_RESOLUTION_FINE = 0.00576
#: Scanner height above the ground (m): the SYNS tripod.
SCANNER_HEIGHT = 1.65
#: Similarity threshold: a true point is matched by an SLR point within this (m).
SIMILARITY_THRESHOLD = 0.10
#: "Close" secondary positions: the paper's 90 % claim holds below this distance (m).
NEAR_DISTANCE = 17.5
#: Ground points a candidate position needs within ``GROUND_COUNT_RADIUS``.
MIN_GROUND_POINTS = 50_000
#: Grid cell of the candidate positions (m).
CELL_SIZE = 2.0
#: Radius of the ground-support count (m).
GROUND_COUNT_RADIUS = 5.0
#: Radius of the ground-height estimate under a position (m).
GROUND_HEIGHT_RADIUS = 3.0
#: Grid spacing of the dense surface samples the primaries are drawn from (m).
DENSE_SPACING = 0.005
#: Scanner heights of Experiment 2's sweep (m).
SWEEP_HEIGHTS = (0.5, 1.0, 1.65, 2.5, 4.0)
#: Question 1 (distance): five scenes of 1000 rectangles.
Q1_SCENES = ("distance-1", "distance-2", "distance-3", "distance-4", "distance-5")
#: Questions 2 and 3 (occlusion, resolution): 0, 500, 1000 and 2000 rectangles.
Q2_SCENES = ("ground-only", "rect-0500", "rect-1000", "rect-2000")
#: Distance bands of the report (m).
DISTANCE_BANDS = ((0.0, 10.0), (10.0, NEAR_DISTANCE), (NEAR_DISTANCE, 25.0), (25.0, 35.0), (35.0, math.inf))
