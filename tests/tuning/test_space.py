"""Search spaces: the paper's decoding, ranges that come from the schema, candidates the schema accepts."""

import numpy as np
import pytest

from uav_depth.core.errors import ConfigError
from uav_depth.core.params import (DEFAULT_PARAMS, OPENCV_3WAY_UNIQUENESS_MAX, OPENCV_COST_MAX,
                                     OPENCV_PRE_FILTER_CAP_FLOOR, SPEC_BY_KEY, SPECS, check_computable,
                                     params_from_dict)
from uav_depth.tuning.paper_space import PAPER_LAYOUT, PaperSpace, decode_number, encode_number
from uav_depth.tuning.space import DEFAULT_KEYS, SchemaSpace, WINNABLE_COST_MAX, build, dim_for, parse_keys
from uav_depth.tuning.choice import fragile_reason


@pytest.mark.parametrize("genes, value", [
    ([1, 1, 1, 1, 1], 1),                       # smallest alpha
    ([10, 10, 10, 10, 10], 100000),             # largest alpha: 9*10000 + 9*1000 + 9*100 + 9*10 + 10
    ([1, 1, 7, 1, 1], 601),                     # (7-1)*100 + 1
    ([2, 3, 4, 5, 6], 12346),                   # 10000 + 2000 + 300 + 40 + 6
    ([1, 10], 10), ([10, 10], 100), ([10, 1], 91), ([1, 1, 1], 1), ([10, 10, 10], 1000),
], ids=lambda x: str(x))
def test_decode_number_is_the_papers_formula(genes, value):
    assert decode_number(genes) == value


@pytest.mark.parametrize("k", [2, 3, 5])
def test_decode_number_is_a_bijection_onto_1_to_10_to_the_k(k):
    if k == 5:
        values = list(range(1, 100001, 997)) + [100000]
    else:
        values = range(1, 10 ** k + 1)
    for v in values:
        assert decode_number(encode_number(v, k)) == v


def test_paper_space_layout_is_29_genes_mapped_onto_the_schema_symbols():
    space = PaperSpace()
    assert space.size == 29
    assert [sym for sym, *_ in PAPER_LAYOUT] == [s.paper for s in SPECS if s.paper]
    assert [g["genes"] for g in space.describe()] == ["x1..x5", "x6..x10", "x11..x12", "x13..x14", "x15..x16",
                                                      "x17..x19", "x20..x22", "x23..x27", "x28..x29"]


def test_paper_symbols_read_the_genes_over_the_papers_ranges():
    space = PaperSpace()
    lo, hi = space.decode_symbols([1] * 29), space.decode_symbols([10] * 29)
    for spec in SPECS:
        if not spec.paper or ".." not in spec.paper_range or "<" in spec.paper_range:
            continue
        a, b = (float(x) for x in spec.paper_range.split(".."))
        assert (lo[spec.paper], hi[spec.paper]) == (a, b), spec.key
    # beta = alpha + number(x6..x10): alpha < beta <= 200000
    assert lo["beta"] == 2 and hi["beta"] == 200000


def test_paper_sigma_uses_two_genes_in_hundredths():
    g = [1] * 29
    g[27], g[28] = 6, 1
    assert PaperSpace().decode(g)["wls.sigma_color"] == 0.5
    g[27], g[28] = 1, 4
    assert PaperSpace().decode(g)["wls.sigma_color"] == 0.03


FLIGHT_LIKE = DEFAULT_PARAMS.replace(**{"sgbm.mode": "sgbm_3way", "sgbm.block_size": 3, "sgbm.num_disparities": 80})


@pytest.mark.parametrize("base", [DEFAULT_PARAMS, FLIGHT_LIKE], ids=["manual", "3way"])
def test_no_paper_genome_builds_a_candidate_the_daemon_would_refuse(base):
    """Every genome decodes into a file the daemon flies (check_computable) and may win (no P1/P2 above the
    winnable bound): no trial fails for a reason the schema knows. On real pairs the paper's ranges failed 30 of
    48 trials (P1/P2 above OpenCV's 16-bit limit)."""
    space, rng = PaperSpace(), np.random.default_rng(0)
    genomes = [space.sample(rng) for _ in range(500)] + [np.full(29, 1), np.full(29, 10)]
    for genome in genomes:
        p = build(space, genome, base)          # raises if the schema refuses it
        check_computable(p)
        assert p.sgbm.p1 < p.sgbm.p2 <= WINNABLE_COST_MAX and fragile_reason(p) is None
        assert p.wls.sigma_color > 0
        if base.sgbm.mode == "sgbm_3way":
            assert p.sgbm.uniqueness_ratio <= OPENCV_3WAY_UNIQUENESS_MAX


def test_paper_penalties_keep_their_place_in_the_papers_range():
    """alpha and beta - alpha are placed, not clipped: the smallest genes give the smallest penalties, the
    largest the largest winnable ones, and the middle of the paper's range the middle of the accepted one."""
    space = PaperSpace()
    lo, hi = space.decode([1] * 29, DEFAULT_PARAMS), space.decode([10] * 29, DEFAULT_PARAMS)
    assert (lo["sgbm.p1"], lo["sgbm.p2"]) == (1, 2)
    assert (hi["sgbm.p1"], hi["sgbm.p2"]) == (WINNABLE_COST_MAX - 1, WINNABLE_COST_MAX)
    mid = [6, 1, 1, 1, 1] + [1] * 24              # alpha 50001: half way
    assert abs(space.decode(mid, DEFAULT_PARAMS)["sgbm.p1"] - WINNABLE_COST_MAX / 2) <= 1
    # every other symbol keeps the paper's own value where the daemon accepts it
    assert lo["sgbm.uniqueness_ratio"] == 1 and hi["sgbm.uniqueness_ratio"] == 100
    assert space.decode([10] * 29, FLIGHT_LIKE)["sgbm.uniqueness_ratio"] == OPENCV_3WAY_UNIQUENESS_MAX
    assert hi["wls.lambda"] == 100000 and lo["wls.sigma_color"] == 0.01      # sigma 0 is one step up


def test_paper_encode_round_trip_and_untuned_keys_keep_the_base():
    base = DEFAULT_PARAMS.replace(**{"wls.sigma_color": 0.25, "sgbm.block_size": 7, "sgbm.num_disparities": 64})
    space = PaperSpace()
    assert build(space, space.encode(base), base) == base
    other = build(space, space.sample(np.random.default_rng(1)), base)
    for spec in SPECS:
        if not spec.paper:
            assert other.get(spec.key) == base.get(spec.key), spec.key


def test_schema_space_bounds_come_from_the_schema_and_opencv_limits():
    for key in DEFAULT_KEYS:
        dim, spec = dim_for(key), SPEC_BY_KEY[key]
        if dim.kind in ("int", "float", "odd"):
            assert spec.lo <= dim.lo and dim.hi <= spec.hi, key
    # P1/P2 stop where a candidate may still win (study.fragile_reason), half of the 16-bit cost limit
    assert dim_for("sgbm.p2").hi == min(SPEC_BY_KEY["sgbm.p2"].hi, WINNABLE_COST_MAX) < OPENCV_COST_MAX
    assert dim_for("sgbm.p1").hi < WINNABLE_COST_MAX
    assert dim_for("sgbm.pre_filter_cap").lo == OPENCV_PRE_FILTER_CAP_FLOOR


def test_the_improved_space_searches_blocks_from_3_and_a_base_at_block_1_still_loads():
    """Block 1 is a file the daemon flies but not one the search proposes (space.SEARCH_FLOORS: where the
    fitness climbs and the safety sweep and the nudge check refuse); the paper's space keeps its own ranges."""
    space, rng = SchemaSpace(), np.random.default_rng(5)
    blocks = {build(space, space.sample(rng), DEFAULT_PARAMS).sgbm.block_size for _ in range(300)}
    assert min(blocks) == 3 and 1 not in blocks and dim_for("sgbm.block_size").lo == 3
    assert build(space, np.zeros(space.size), DEFAULT_PARAMS).sgbm.block_size == 3
    one = FLIGHT_LIKE.replace(**{"sgbm.block_size": 1})
    assert build(space, space.encode(one), one).sgbm.block_size == 3     # the base itself is evaluated apart


def test_schema_space_candidates_always_validate_and_keep_the_declared_rules():
    keys = parse_keys("default,sgbm.mode,sgbm.num_disparities,wls.enabled")
    space, rng = SchemaSpace(keys), np.random.default_rng(3)
    for i in range(400):
        genome = space.sample(rng) if i > 3 else np.full(space.size, [0.0, 1.0, 0.5, 0.999999][i])
        p = build(space, genome, DEFAULT_PARAMS)       # raises if the schema rejects it
        assert p.sgbm.p1 < p.sgbm.p2 <= WINNABLE_COST_MAX
        assert fragile_reason(p) is None           # nothing searched is refused for its penalties
        assert p.sgbm.block_size % 2 == 1 and p.sgbm.num_disparities % 16 == 0
        assert not p.sgbm.overflows


def test_schema_space_encodes_the_baseline_exactly():
    space = SchemaSpace(parse_keys("default,sgbm.mode"))
    assert build(space, space.encode(DEFAULT_PARAMS), DEFAULT_PARAMS) == DEFAULT_PARAMS


def test_schema_space_log_scale_spends_equal_effort_per_decade():
    dim = dim_for("sgbm.p1")
    values = [dim.decode(u) for u in np.linspace(0, 1, 1001)]
    below_100 = np.mean(np.array(values) < 100)
    assert 0.35 < below_100 < 0.55   # log10(100) / log10(32766) = 0.44; linear would give 0.003


def test_schema_space_uniqueness_respects_the_3way_cap_of_the_base_or_the_tuned_mode():
    for keys, base in ((("sgbm.uniqueness_ratio",), FLIGHT_LIKE), (("sgbm.uniqueness_ratio", "sgbm.mode"), DEFAULT_PARAMS)):
        space = SchemaSpace(keys)
        assert space.keys[0] == keys[-1]          # the mode (when tuned) is decoded first
        for u in np.linspace(0, 1, 41):
            genome = [u] * space.size
            p = build(space, genome, base)
            assert p.sgbm.mode != "sgbm_3way" or p.sgbm.uniqueness_ratio <= OPENCV_3WAY_UNIQUENESS_MAX


def test_schema_space_p2_alone_stays_above_the_bases_p1():
    space = SchemaSpace(("sgbm.p2",))
    base = DEFAULT_PARAMS.replace(**{"sgbm.p1": 5000, "sgbm.p2": 6000})
    assert all(build(space, [u], base).sgbm.p2 > 5000 for u in (0.0, 0.3, 1.0))


def test_every_schema_key_of_a_searchable_kind_can_be_tuned():
    # new keys in SPECS (e.g. compute.*) are picked up without edits here
    for spec in SPECS:
        if spec.kind in (int, float, bool) or spec.choices:
            space = SchemaSpace((spec.key,))
            p = build(space, space.sample(np.random.default_rng(0)), DEFAULT_PARAMS)
            assert params_from_dict(p.to_dict()) == p


@pytest.mark.parametrize("text, match", [
    ("sgbm.nope", "--keys must name parameter-file keys"),
    ("sgbm.p1,wls.lamda", "'wls.lamda'"),
], ids=["unknown", "typo"])
def test_bad_keys_are_clear(text, match):
    with pytest.raises(ConfigError, match=match):
        parse_keys(text)
