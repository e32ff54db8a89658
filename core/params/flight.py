"""What flies: the recommended flight settings, read from the parameter files the project ships.

``deploy/params-flight.yaml`` (1280x720, focal 700 px) is the one source of the
values; the package carries it as data (``shipped/``, which links to ``deploy/`` in a
checkout and holds a copy in a built package), so an installed ``uav-depth`` reads the
same file ``deploy/install.sh`` installs. :func:`flight_params` gives the same settings
for another camera: the file with the disparity search its working distance needs at
that focal length and baseline (``deploy/params-flight-640x360.yaml`` is it for focal 350 px).
"""

from __future__ import annotations

from pathlib import Path

from uav_depth.core.params.checks import disparity_search_range
from uav_depth.core.params.file import load_params, read_provenance
from uav_depth.core.params.schema import StereoParams

#: The shipped parameter files (package data).
SHIPPED = Path(__file__).resolve().with_name("shipped")
#: The flight settings for a ZED Mini-like camera at 1280x720 (focal 700 px, baseline 63 mm).
FLIGHT_FILE = SHIPPED / "params-flight.yaml"
#: The same for 640x360 (focal 350 px): the simulator's SITL example.
FLIGHT_640X360_FILE = SHIPPED / "params-flight-640x360.yaml"


def flight_working_distance_m() -> tuple[float, float]:
    """The flight file's working distance (its provenance), (near, far) m: 0.3..3 m, where the pruning tool works."""
    near, far = read_provenance(FLIGHT_FILE)["working_distance_m"]
    return float(near), float(far)


def flight_params(focal_px: float = 700.0, baseline_m: float = 0.063) -> StereoParams:
    """The recommended flight settings for a camera (the shipped file's camera by default).

    :data:`FLIGHT_FILE` with ``sgbm.min_disparity``/``sgbm.num_disparities`` covering its
    working distance from its near end (:func:`flight_working_distance_m`) at this focal
    length (px) and baseline (m), at the file's ``compute.scale``; every other value is the
    file's.
    """
    params = load_params(FLIGHT_FILE)
    near_m, _ = flight_working_distance_m()
    min_d, num_d = disparity_search_range(focal_px, baseline_m, near_m, scale=params.compute.scale)
    return params.replace(**{"sgbm.min_disparity": min_d, "sgbm.num_disparities": num_d})
