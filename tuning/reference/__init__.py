"""Reference disparity for tuning: import it, compute it with an ONNX stereo network, record where it came from.

- :mod:`.formats`: readers for npy / pfm / kitti-png / middlebury-png with a scale.
- :mod:`.check`: a sample SGBM run that flags a reference in the wrong unit.
- :mod:`.importer`: ``uav-depth reference import``.
- :mod:`.network`: ``uav-depth reference onnx`` (onnxruntime, the ``onnx`` extra).
- :mod:`.provenance`: the ``FRAMEID_ref.json`` beside each ``FRAMEID_ref.npy``, and
  the summary reports print of what a tuning run was measured against.

With no reference at all, :mod:`uav_depth.tuning.selfsup` scores disparity without one.
"""

from uav_depth.tuning.reference.provenance import (KINDS, describe, has_reference_to_keep, make_provenance, read_provenance,
                         summarize_references, write_reference)

__all__ = ["KINDS", "describe", "has_reference_to_keep", "make_provenance", "read_provenance",
           "summarize_references", "write_reference"]
