"""A reference of another scene is given up after the early rungs; a true pair never is (real DEV
pairs from ../shared/data/pairs, skipped when absent; the rule's measurement:
benchmarks/studies/unrelated_rule.py)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from geofill import FillConfig
from geofill.evaluation.pairs import load_pair, pair_mask
from geofill.match import match_pair
from geofill.match.ladder import EARLY_RUNGS, another_scene
from geofill.prepare import prepare_views


def early_rungs(pairs_dir, target_pair: str, source_pair: str, seed: int):
    """The ladder's early rungs on ``target_pair``'s target (the evaluation's hole of ``seed``)
    against ``source_pair``'s reference, every one forced to run, as the match stage sees them."""
    cfg = FillConfig()
    t, s = load_pair(pairs_dir / target_pair), load_pair(pairs_dir / source_pair)
    last = [r for r in ("sift", "learned", "loose") if r in EARLY_RUNGS][-1]
    forced = replace(cfg.matching, max_rung=last, min_verified=10**6, unrelated_max_verified=0, learned="off")
    v = prepare_views(t.target, pair_mask(t, seed), s.source, cfg, None, None)
    m = match_pair(v.target_gray, v.source_gray, v.hole, forced, v.px_scale, (v.K_target.K, v.K_source.K))
    return list(m.rungs), cfg.matching


def test_a_wide_true_pair_with_few_sift_matches_is_not_given_up(pairs_dir):
    # The tower's wide pair at hole seed 1: SIFT verifies 10 matches, fewer than the old limit of 15,
    # and the pair was dropped as showing another scene.
    reports, cfg = early_rungs(pairs_dir, *["dev_wide_mast3r_nle_tower_ff55_to_91e9"] * 2, seed=1)
    assert reports[0].rung == "sift" and reports[0].n_verified < 15
    assert another_scene(reports, cfg) == ""


def test_a_reference_of_another_scene_is_given_up(pairs_dir):
    reports, cfg = early_rungs(pairs_dir, "dev_instantngp_fox_a", "dev_kitti_stereo_gray", seed=0)
    assert another_scene(reports, cfg).startswith("does not show the same scene as the target")


@pytest.mark.parametrize("seed", [0, 5])
def test_the_wide_living_room_pair_is_not_given_up(pairs_dir, seed):
    reports, cfg = early_rungs(pairs_dir, *["dev_wide_slambook_livingroom_f1_to_f2"] * 2, seed=seed)
    assert another_scene(reports, cfg) == ""
