"""The stereo parameter schema: every key of the parameter file declared once, and the frozen parameters.

Every key is declared once in :data:`SPECS` with its type, bounds, rule and the
paper's symbol. The loader and writer (:mod:`.file`), the tuner's search spaces and
the docs' table all read this table; nothing else states a range.

The defaults are the *manual configuration* baseline: OpenCV's own sample values
(``samples/python/stereo_match.py``: P1 = 8*3*block_size**2, P2 = 32*3*block_size**2,
disp12MaxDiff 1, uniquenessRatio 10, speckle 100/32; ``disparity_filtering.cpp``:
lambda 8000, sigma 1.5). The tuner reports its gains against them.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from typing import Any, Mapping

from uav_depth.core.errors import ConfigError
from uav_depth.core.validate import fmt, in_range, number

#: OpenCV's SGBM stores P1, P2 and path costs in 16-bit signed integers (CostType
#: is short). A penalty above this wraps around and the matcher returns garbage.
#: Verified on OpenCV 5.0.0: P2=32768 gives maximum disparity 0 on the motorcycle
#: pair. The pipeline answers such parameters with an all-NaN map and a warning.
OPENCV_COST_MAX = 32767

#: OpenCV clamps preFilterCap from below: SGBM uses max(preFilterCap, 15).
#: Verified on OpenCV 5.0.0: values 1..15 give bit-identical disparities.
OPENCV_PRE_FILTER_CAP_FLOOR = 15

#: OpenCV's 3-way SGBM divides by 100 - uniquenessRatio (verified on 5.0.0: 100 raises SIGFPE, a native
#: crash no Python handler can catch); the other modes take 100.
OPENCV_3WAY_UNIQUENESS_MAX = 99

MODES = ("sgbm", "sgbm_3way", "hh", "hh4")


@dataclass(frozen=True)
class Spec:
    """Declaration of one parameter-file key.

    ``lo``/``hi`` are inclusive bounds; ``rule`` is an extra rule (``odd``,
    ``multiple_of_16``, ``positive``); ``paper`` names the symbol of Lin et al. 2025
    and ``paper_range`` the range the paper searches.
    """

    section: str
    name: str
    kind: type
    default: Any
    doc: str
    lo: float | None = None
    hi: float | None = None
    rule: str | None = None
    choices: tuple[str, ...] | None = None
    paper: str | None = None
    paper_range: str | None = None

    @property
    def key(self) -> str:
        return f"{self.section}.{self.name}"

    def check(self, value: Any, source: str | None = None) -> Any:
        """Return ``value`` converted to this key's type, or raise ConfigError."""
        key = self.key
        if self.kind is tuple:
            return self._check_box(value, source)
        if self.kind is bool:
            if not isinstance(value, bool):
                raise ConfigError(key, "must be true or false", value, source)
            return value
        if self.choices is not None:
            if value not in self.choices:
                raise ConfigError(key, f"must be one of {', '.join(self.choices)}", value, source)
            return value
        value = number(key, value, self.kind is int, source)
        in_range(key, value, self.lo, self.hi, source)
        if self.rule == "odd" and value % 2 != 1:
            raise ConfigError(key, "must be odd", value, source)
        if self.rule == "multiple_of_16" and value % 16 != 0:
            raise ConfigError(key, "must be a positive multiple of 16", value, source)
        if self.rule == "zero_or_multiple_of_16" and value % 16 != 0:
            raise ConfigError(key, "must be 0 (off) or a multiple of 16", value, source)
        if self.rule == "positive" and not value > 0:
            raise ConfigError(key, "must be greater than 0", value, source)
        return value


    def _check_box(self, value: Any, source: str | None) -> tuple[float, ...]:
        """A region [left, top, right, bottom] with every number in lo..hi and left < right, top < bottom."""
        key = self.key
        if (not isinstance(value, (list, tuple)) or len(value) != 4
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)):
            raise ConfigError(key, "must be a list of 4 numbers [left, top, right, bottom]", value, source)
        box = tuple(float(v) for v in value)
        if not all(math.isfinite(v) and self.lo <= v <= self.hi for v in box):
            raise ConfigError(key, f"must have every number between {fmt(self.lo)} and {fmt(self.hi)}",
                              list(value), source)
        if not (box[0] < box[2] and box[1] < box[3]):
            raise ConfigError(key, "must have left < right and top < bottom", list(value), source)
        return box


SPECS: tuple[Spec, ...] = (
    Spec("sgbm", "min_disparity", int, 0, "smallest disparity searched, px", -256, 256),
    Spec("sgbm", "num_disparities", int, 128, "disparity search range, px", 16, 1024, "multiple_of_16"),
    Spec("sgbm", "block_size", int, 5, "matched block size, px", 1, 31, "odd"),
    Spec("sgbm", "mode", str, "sgbm", "OpenCV SGBM mode", choices=MODES),
    Spec("sgbm", "p1", int, 600, "small smoothness penalty (disparity change of 1)", 1, 100000,
         paper="alpha", paper_range="1..100000"),
    Spec("sgbm", "p2", int, 2400, "large smoothness penalty (larger change); must exceed p1", 2, 200000,
         paper="beta", paper_range="alpha < beta <= 200000"),
    Spec("sgbm", "disp12_max_diff", int, 1, "left-right consistency threshold, px (-1 disables)", -1, 1000,
         paper="Delta", paper_range="1..100"),
    Spec("sgbm", "pre_filter_cap", int, 63, "clip of the prefiltered x-derivative (OpenCV uses max(value, 15))",
         1, 1023, paper="eta", paper_range="1..100"),
    Spec("sgbm", "uniqueness_ratio", int, 10, "margin in % by which the best cost must win", 0, 100,
         paper="gamma", paper_range="1..100"),
    Spec("sgbm", "speckle_window_size", int, 100, "largest speckle region removed, px (0 disables)", 0, 10000,
         paper="W", paper_range="1..1000"),
    Spec("sgbm", "speckle_range", int, 32, "disparity variation inside a speckle region (x16 internally)", 0, 10000,
         paper="delta", paper_range="1..1000"),
    Spec("wls", "enabled", bool, True, "run the WLS filter with a right matcher"),
    Spec("wls", "lambda", float, 8000.0, "WLS regularisation strength", 0.0, 1.0e6,
         paper="lambda", paper_range="1..100000"),
    Spec("wls", "sigma_color", float, 1.5, "WLS sensitivity to guide-image edges", 0.0, 100.0, "positive",
         paper="sigma", paper_range="0..0.99"),
    # Speed levers. Each changes the computed disparity, so they live here and the
    # tuner scores with them; the defaults (full frame, full resolution, colour as
    # given) are the manual baseline, computed exactly as before they existed.
    Spec("compute", "roi", tuple, (0.0, 0.0, 1.0, 1.0),
         "region matched [left, top, right, bottom], fractions of the left image; NaN outside", 0.0, 1.0, "box"),
    Spec("compute", "scale", float, 1.0,
         "matching resolution as a fraction of the input; sgbm.* then count matched pixels, disparities "
         "come back in input pixels", 0.125, 1.0),
    Spec("compute", "grey", bool, False, "match grey images (colour input converted first)"),
    Spec("compute", "wls_at", str, "input",
         "with scale < 1: WLS filters at the input resolution with the full-resolution guide, or at the "
         "matched resolution and is resized", choices=("input", "matched")),
    Spec("compute", "fine_disparities", int, 0,
         "with scale < 1: re-match the ranged object's box at full resolution over this many disparities "
         "just below and above its coarse disparity, and range on that (docs/ranging.md); 0: off", 0, 256,
         "zero_or_multiple_of_16"),
)

SPEC_BY_KEY: dict[str, Spec] = {s.key: s for s in SPECS}

#: Rules between keys, declared once: the loader checks them (:func:`params_from_dict`) and the tuner's search
#: spaces decode inside them (:func:`accepted_range`), so no candidate is built that the schema refuses.
#: (key, other, gap): ``key`` must be at least ``other`` + gap (SGBM needs P2 > P1).
ABOVE: tuple[tuple[str, str, int], ...] = (("sgbm.p2", "sgbm.p1", 1),)
#: (key, other, least): ``key`` + ``other`` must be at least ``least``: the search must reach a positive disparity
#: (min_disparity + num_disparities - 1 >= 1), since the ranging and the near pass divide by the largest one.
SUM_AT_LEAST: tuple[tuple[str, str, int], ...] = (("sgbm.num_disparities", "sgbm.min_disparity", 2),)
#: (key, other, when, cap, why): ``key`` must be at most ``cap`` while ``other`` is ``when``.
CAPPED_WHEN: tuple[tuple[str, str, Any, int, str], ...] = (
    ("sgbm.uniqueness_ratio", "sgbm.mode", "sgbm_3way", OPENCV_3WAY_UNIQUENESS_MAX,
     "OpenCV's 3-way matcher divides by 100 - uniquenessRatio: 100 kills the process"),
)
#: The largest value OpenCV computes with, whatever the image (:func:`check_computable`): SGBM's 16-bit costs.
COMPUTABLE_MAX: dict[str, int] = {"sgbm.p1": OPENCV_COST_MAX, "sgbm.p2": OPENCV_COST_MAX}


def accepted_range(key: str, values: Mapping[str, Any], limits: Mapping[str, float] | None = None
                   ) -> tuple[float, float]:
    """The inclusive range of numeric ``key`` that a file the daemon flies may hold, given the other keys'
    ``values`` (dotted key -> value; a key not in it does not narrow the range): the key's bounds, OpenCV's
    :data:`COMPUTABLE_MAX`, and the rules between keys (:data:`ABOVE`, :data:`SUM_AT_LEAST`, :data:`CAPPED_WHEN`).
    ``limits``: further caps (key -> largest value) a caller applies to any key, and so to the keys that must
    stay above it. A ``positive`` key's lower bound is exclusive (its rule)."""
    spec = SPEC_BY_KEY[key]
    lo, hi = float(spec.lo), float(min(spec.hi, COMPUTABLE_MAX.get(key, spec.hi), (limits or {}).get(key, spec.hi)))
    for k, other, gap in ABOVE:
        if k == key and values.get(other) is not None:
            lo = max(lo, float(values[other] + gap))
        if other == key:                # room for the key that must stay above this one
            hi = min(hi, accepted_range(k, {}, limits)[1] - gap)
    for k, other, least in SUM_AT_LEAST:
        if k == key and values.get(other) is not None:
            lo = max(lo, float(least - values[other]))
    for k, other, when, cap, _ in CAPPED_WHEN:
        if k == key and values.get(other) == when:
            hi = min(hi, float(cap))
    return lo, hi
SECTIONS: tuple[str, ...] = tuple(dict.fromkeys(s.section for s in SPECS))
#: Top-level keys that are accepted and carried but are not parameters.
META_KEYS = ("provenance",)

_MODE_FLAGS = {"sgbm": 0, "hh": 1, "sgbm_3way": 2, "hh4": 3}  # cv2.StereoSGBM_MODE_*


@dataclass(frozen=True)
class SGBMParams:
    min_disparity: int = 0
    num_disparities: int = 128
    block_size: int = 5
    mode: str = "sgbm"
    p1: int = 600
    p2: int = 2400
    disp12_max_diff: int = 1
    pre_filter_cap: int = 63
    uniqueness_ratio: int = 10
    speckle_window_size: int = 100
    speckle_range: int = 32

    @property
    def mode_flag(self) -> int:
        return _MODE_FLAGS[self.mode]

    @property
    def overflows(self) -> bool:
        """True when OpenCV's 16-bit costs cannot hold the penalties."""
        return self.p2 > OPENCV_COST_MAX or self.p1 > OPENCV_COST_MAX


@dataclass(frozen=True)
class WLSParams:
    enabled: bool = True
    lambda_: float = 8000.0
    sigma_color: float = 1.5


@dataclass(frozen=True)
class ComputeParams:
    """Where and how finely to match (see the ``compute.*`` keys)."""

    roi: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 1.0)
    scale: float = 1.0
    grey: bool = False
    wls_at: str = "input"
    fine_disparities: int = 0

    @property
    def whole_frame(self) -> bool:
        """No matching region: the pipeline answers (and is scored) over the whole image."""
        return self.roi == (0.0, 0.0, 1.0, 1.0)

    @property
    def fine_pass(self) -> bool:
        """The flight pipeline re-matches the ranged object at full resolution: ``fine_disparities`` is set
        and the main match is below full resolution (at scale 1 it already is full resolution)."""
        return self.fine_disparities > 0 and self.scale < 1.0

    @property
    def is_baseline(self) -> bool:
        """Full frame, full resolution, colour as given: the manual baseline's computation."""
        return self.whole_frame and self.scale == 1.0 and not self.grey

    def roi_pixels(self, width: int, height: int) -> tuple[int, int, int, int]:
        """The region in pixels of a ``width`` x ``height`` image: (x0, y0, x1, y1), x1/y1 exclusive.

        Fractions are rounded to the nearest pixel edge; the box keeps at least one
        pixel. The pipeline answers inside this box only; scorers (the tuner) and
        ranging read the same box from here.
        """
        left, top, right, bottom = self.roi
        x0 = min(int(math.floor(left * width + 0.5)), width - 1)
        y0 = min(int(math.floor(top * height + 0.5)), height - 1)
        x1 = max(int(math.floor(right * width + 0.5)), x0 + 1)
        y1 = max(int(math.floor(bottom * height + 0.5)), y0 + 1)
        return x0, y0, x1, y1


@dataclass(frozen=True)
class StereoParams:
    """Validated, frozen SGBM + WLS parameters. Build with :func:`params_from_dict`."""

    sgbm: SGBMParams = SGBMParams()
    wls: WLSParams = WLSParams()
    compute: ComputeParams = ComputeParams()

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Plain nested dict in file order, with the file's key names (a region as a list)."""
        out: dict[str, dict[str, Any]] = {}
        for spec in SPECS:
            value = self.get(spec.key)
            out.setdefault(spec.section, {})[spec.name] = list(value) if isinstance(value, tuple) else value
        return out

    def get(self, key: str) -> Any:
        section, name = key.split(".")
        return getattr(getattr(self, section), _attr(name))

    def replace(self, **changes: Any) -> "StereoParams":
        """Return a validated copy with dotted keys changed: ``replace(**{"sgbm.p1": 8})``."""
        d = self.to_dict()
        for key, value in changes.items():
            section, name = key.split(".")
            d[section][name] = value
        return params_from_dict(d)

    def hash(self) -> str:
        """Short stable hash of the parameter values (12 hex digits)."""
        blob = json.dumps(self.to_dict(), sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:12]


def _attr(name: str) -> str:
    return "lambda_" if name == "lambda" else name


DEFAULT_PARAMS = StereoParams()


def params_from_dict(data: Any, source: str | None = None) -> StereoParams:
    """Validate a nested mapping (as read from YAML) into :class:`StereoParams`.

    Missing keys take their defaults; unknown keys are errors (a typo must not
    silently fall back to a default).
    """
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError("(top level)", "must be a mapping of sections", type(data).__name__, source)
    for top in data:
        if top not in SECTIONS and top not in META_KEYS:
            raise ConfigError(str(top), f"is not a known section (known: {', '.join(SECTIONS)})", data[top], source)
    values: dict[str, dict[str, Any]] = {s: {} for s in SECTIONS}
    for section in SECTIONS:
        given = data.get(section) or {}
        if not isinstance(given, Mapping):
            raise ConfigError(section, "must be a mapping", given, source)
        known = {s.name for s in SPECS if s.section == section}
        for name in given:
            if name not in known:
                raise ConfigError(f"{section}.{name}", f"is not a known key (known: {', '.join(sorted(known))})",
                                  given[name], source)
        for spec in (s for s in SPECS if s.section == section):
            raw = given.get(spec.name, spec.default)
            values[section][_attr(spec.name)] = spec.check(raw, source)
    _check_rules(values, source)
    return StereoParams(sgbm=SGBMParams(**values["sgbm"]), wls=WLSParams(**values["wls"]),
                        compute=ComputeParams(**values["compute"]))


def _check_rules(values: Mapping[str, Mapping[str, Any]], source: str | None) -> None:
    """The rules between keys (:data:`ABOVE`, :data:`SUM_AT_LEAST`, :data:`CAPPED_WHEN`) on validated values."""
    def get(key: str) -> Any:
        section, name = key.split(".")
        return values[section][_attr(name)]

    for key, other, gap in ABOVE:
        if get(key) < get(other) + gap:
            rule = "greater than" if gap == 1 else f"at least {gap} above"
            raise ConfigError(key, f"must be {rule} {other} ({get(other)})", get(key), source)
    for key, other, least in SUM_AT_LEAST:
        if get(key) + get(other) < least:
            raise ConfigError(key, f"must reach positive disparities: with {other} {get(other)} the largest "
                              f"disparity searched (min_disparity + num_disparities - 1) must be at least {least - 1} "
                              "(ranging and the near pass divide by it)", get(key), source)
    for key, other, when, cap, why in CAPPED_WHEN:
        if get(other) == when and get(key) > cap:
            raise ConfigError(key, f"must be at most {cap} with {other} {when} ({why})", get(key), source)


def params_table_markdown() -> str:
    """The README's table of keys, defaults, bounds and the paper's symbols."""
    rows = ["| key | default | accepted | paper symbol | paper range | meaning |", "|---|---|---|---|---|---|"]
    for s in SPECS:
        if s.choices:
            acc = " / ".join(s.choices)
        elif s.kind is tuple:
            acc = f"4 numbers {fmt(s.lo)}..{fmt(s.hi)}, left < right, top < bottom"
        elif s.kind is bool:
            acc = "true / false"
        else:
            acc = f"{fmt(s.lo)}..{fmt(s.hi)}" + (f", {s.rule.replace('_', ' ')}" if s.rule else "")
        default = list(s.default) if isinstance(s.default, tuple) else s.default
        rows.append(f"| `{s.key}` | {default} | {acc} | {s.paper or ''} | {s.paper_range or ''} | {s.doc} |")
    return "\n".join(rows)
