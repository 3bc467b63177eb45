"""ExtractSettings: today's defaults, validation naming the option, dict round trips, extract() overrides."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from seed2gs_inverse import ValidationError
from seed2gs_inverse.pipeline import ExtractSettings, extract
from seed2gs_inverse.pipeline.settings import SOLVER_DEFAULTS
from seed2gs_inverse.synthetic import make_scene

# The keyword defaults of extract() before issue 9 (its signature, copied):
# the settings object must keep every one of them.
DEFAULTS_BEFORE = {
    "method": "weighted_bce", "n_views": 24, "a_max_deg": 60.0, "gamma": 1.0, "skip_deg": 5.0,
    "profile": "linear", "max_elevation_deg": 85.0, "orbit_scale": 0.5, "max_view_pixels": 40_000,
    "max_reference_pixels": 1_000_000, "roi_margin": 2.0, "zoom_margin": 2.0, "up": "level",
    "min_weight": 0.0, "cull": True, "cull_far": 4.0, "min_evidence": 1.0, "threshold": None,
    "lift_options": None, "solver_options": None, "mode": "classic", "progress": None}

# Issue 10 (measured on benchmarks/bench_up_axis.py and bench_extract.py):
# the orbit axis is estimated ("auto"), a point prompt returns the object, and
# smoothness=None turns the graph regulariser on for the model-free tracker
# (resolved["smoothness"]); the orbit operators drop weights below 0.01 and
# the model-free tracker labels the support surface background. New options
# come after the old ones. Faint Gaussians near the object follow their opaque neighbours
# (benchmarks/bench_scanned.py); the orbit views cut what stands in front of the object
# (near_margin, measured on bench_extract.py and tests/test_occluded_views.py); Gaussians that
# dominate no pixel follow their strong neighbours (follow_weak, measured on bench_extract.py); a
# Gaussian whose masks mostly call it background is not selected (min_vote, bench_extract.py); a mask
# prompt may miss its object's edge by 3 px (mask_tolerance, bench_extract.py --mask-error).
DEFAULTS = {**DEFAULTS_BEFORE, "up": "auto", "min_weight": 0.01, "point_mode": "object", "smoothness": None,
            "completion": None, "graph_options": None, "seed_connected": True, "support_background": True,
            "follow_faint": True, "near_margin": 1.0, "follow_weak": True, "min_vote": 0.2,
            "mask_tolerance": 3}


def test_defaults_are_those_of_the_old_extract_but_issue_10s():
    s = ExtractSettings()
    assert ExtractSettings.names() == list(DEFAULTS)
    for name, want in DEFAULTS.items():
        got = getattr(s, name)
        if want is None and name.endswith("_options"):  # lift_, solver_, graph_options
            assert dict(got) == {}, name  # None meant "no options"
        else:
            assert got == want and type(got) is type(want), name
    assert s.solver_kwargs() == SOLVER_DEFAULTS["weighted_bce"] == {"max_iter": 20}
    assert ExtractSettings(method="voting").solver_kwargs() == {}
    assert ExtractSettings(solver_options={"max_iter": 5}).solver_kwargs() == {"max_iter": 5}


@pytest.mark.parametrize("name,value,match", [
    ("method", "newton", "unknown solver method 'newton'"),
    ("n_views", 1, r"n_views must be in 2\.\.360"),
    ("n_views", 10 ** 7, r"n_views must be in 2\.\.360, got 10000000"),  # was a hang (issue 12 item 7)
    ("n_views", float("nan"), "n_views must be an integer"),
    ("n_views", 2.5, "n_views must be an integer"),
    ("n_views", True, "n_views must be an integer"),
    ("a_max_deg", -1.0, "a_max_deg must be >= 0"),
    ("a_max_deg", float("nan"), "a_max_deg must be finite"),
    ("gamma", 0.0, "gamma must be > 0"),
    ("skip_deg", float("inf"), "skip_deg must be finite"),
    ("profile", "cubic", "profile must be one of"),
    ("max_elevation_deg", 90.0, "max_elevation_deg must be < 90"),
    ("orbit_scale", 0.0, "orbit_scale must be > 0"),
    ("orbit_scale", 5.0, "orbit_scale must be <= 4"),
    ("orbit_scale", "half", "orbit_scale must be a number"),
    ("min_weight", 1.5, "min_weight must be <= 1"),  # refused here, not at the operators stage
    ("max_view_pixels", 10, r"max_view_pixels must be in 64\.\.16,777,216"),
    ("max_view_pixels", 10 ** 12, r"max_view_pixels must be in 64\.\.16,777,216"),
    ("max_view_pixels", 1e5, "max_view_pixels must be an integer or None"),
    ("max_reference_pixels", 0, "max_reference_pixels must be in 64..67,108,864"),
    ("max_reference_pixels", 2 ** 40, "max_reference_pixels must be in 64..67,108,864"),
    ("roi_margin", 0.0, "roi_margin must be > 0"),
    ("zoom_margin", float("nan"), "zoom_margin must be finite"),
    ("up", "sideways", "up must be one of"),
    ("up", (0.0, 0.0, 0.0), "up must be 'auto', 'level', 'camera' or a non-zero"),
    ("up", (0.0, 1.0), "up must be 'auto', 'level', 'camera' or a non-zero"),
    ("point_mode", "click", "point_mode must be one of 'object', 'region'"),
    ("smoothness", -1.0, "smoothness must be >= 0"),
    ("smoothness", float("inf"), "smoothness must be finite"),
    ("smoothness", "1", "smoothness must be a number or None"),
    ("completion", "both", "completion must be None, 'reference' or 'tracked'"),
    ("completion", np.array([1, 2]), "completion must be None, 'reference' or 'tracked'"),  # was numpy's error
    ("a_max_deg", 10 ** 400, "a_max_deg must be finite"),  # was an OverflowError from float()
    ("seed_connected", 1, "seed_connected must be True or False"),
    ("support_background", "yes", "support_background must be True or False"),
    ("graph_options", {"kk": 3}, r"object_graph has no option\(s\) \['kk'\]"),
    ("graph_options", {"k": 0}, r"graph_options k must be in 1\.\.256"),
    ("graph_options", {"k": 10 ** 6}, r"graph_options k must be in 1\.\.256"),
    ("graph_options", {"sigma_color": -0.1}, "graph_options sigma_color must be > 0"),
    ("graph_options", {"region": 0.0}, "graph_options region must be > 0"),
    ("graph_options", {"min_opacity": 1.0}, "graph_options min_opacity must be < 1"),
    ("min_weight", -1e-3, "min_weight must be >= 0"),
    ("cull", 1, "cull must be True or False"),
    ("cull_far", -1.0, "cull_far must be > 0"),
    ("near_margin", 0.0, "near_margin must be > 0"),
    ("near_margin", float("nan"), "near_margin must be finite"),
    ("min_evidence", float("nan"), "min_evidence must be finite"),
    ("min_evidence", -0.1, "min_evidence must be >= 0"),
    ("min_vote", -0.1, "min_vote must be >= 0"),
    ("min_vote", 1.5, "min_vote must be <= 1"),
    ("min_vote", float("nan"), "min_vote must be finite"),
    ("threshold", float("inf"), "threshold must be finite"),
    ("threshold", float("nan"), "threshold must be finite"),  # selected nothing (issue 12 item 6)
    ("threshold", 2.0, r"threshold must be in \[0, 1\)"),
    ("threshold", 1.0, r"threshold must be in \[0, 1\)"),
    ("threshold", -0.5, "threshold must be >= 0"),
    ("lift_options", {"eps": 1.0}, "seed_lift has no option"),
    ("lift_options", {"eps_rell": 0.1}, r"seed_lift has no option\(s\) \['eps_rell'\]; its options are"),
    ("lift_options", {"k_neighbors": 10 ** 7}, r"k_neighbors must be in 1\.\.256"),
    # each seed_lift option, refused here instead of as a numpy error (or silently) mid-pipeline
    ("lift_options", {"eps_rel": "abc"}, "lift_options eps_rel must be a number"),
    ("lift_options", {"eps_sigma": float("nan")}, "lift_options eps_sigma must be finite"),
    ("lift_options", {"min_membership": 1.5}, "lift_options min_membership must be <= 1.0"),
    ("lift_options", {"min_weight": [1, 2]}, "lift_options min_weight must be a number"),
    ("lift_options", {"link_factor": 0}, "lift_options link_factor must be > 0.0"),
    ("lift_options", {"keep_fraction": 5.0}, "lift_options keep_fraction must be <= 1.0"),
    ("lift_options", {"max_size_ratio": -1}, "lift_options max_size_ratio must be > 0.0"),
    ("lift_options", [1], "lift_options must be a dict"),
    ("solver_options", {"max_iterations": 3}, "has no option"),
    ("solver_options", {"max_iter": 10 ** 9}, r"max_iter must be in 1\.\.100,000"),
    ("solver_options", {"max_iter": 0}, r"max_iter must be in 1\.\.100,000"),
    ("mode", "fancy", "mode must be one of"),
    ("progress", "yes", "progress must be None, True, False, 'bars' or 'lines'"),
    ("progress", "quiet", "progress must be None, True, False"),
    ("progress", 1, "progress must be None, True, False"),
])
def test_validation_names_the_option(name, value, match):
    with pytest.raises(ValidationError, match=match):
        ExtractSettings(**{name: value})


def test_values_are_normalised_and_frozen():
    s = ExtractSettings(n_views=np.int64(6), a_max_deg=45, up=np.array([0, 0, 2]), lift_options={"eps_rel": 0.03},
                        cull=np.bool_(False))
    assert type(s.n_views) is int and s.n_views == 6
    assert type(s.a_max_deg) is float and s.a_max_deg == 45.0
    assert s.up == (0.0, 0.0, 2.0) and s.cull is False
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.n_views = 8
    with pytest.raises(TypeError):
        s.lift_options["eps_rel"] = 1.0  # read-only: the settings cannot change behind extract's back
    src = {"max_iter": 3}
    t = ExtractSettings(solver_options=src)
    src["max_iter"] = 99
    assert t.solver_options["max_iter"] == 3


def test_to_dict_from_dict_round_trip_through_json():
    s = ExtractSettings(method="voting", n_views=7, up=(0.0, -1.0, 0.0), max_view_pixels=None, threshold=0.4,
                        lift_options={"eps_rel": 0.03}, cull_far=None, profile="sin", progress=False)
    d = s.to_dict()
    assert list(d) == ExtractSettings.names()
    text = json.dumps(d)
    back = ExtractSettings.from_dict(json.loads(text))
    assert back == s and back.to_dict() == d
    assert d["up"] == [0.0, -1.0, 0.0] and d["lift_options"] == {"eps_rel": 0.03}
    # missing keys take their defaults
    assert ExtractSettings.from_dict({"n_views": 5}) == ExtractSettings(n_views=5)
    assert ExtractSettings.from_dict(ExtractSettings().to_dict()) == ExtractSettings()


def test_unknown_keys_are_rejected_listing_the_valid_ones():
    with pytest.raises(ValidationError, match=r"\['nviews'\].*valid names: method, n_views, a_max_deg"):
        ExtractSettings.from_dict({"nviews": 3})
    with pytest.raises(ValidationError, match="must be a dict"):
        ExtractSettings.from_dict([("n_views", 3)])
    with pytest.raises(ValidationError, match=r"\['view_count'\].*valid names: .*min_evidence"):
        ExtractSettings().replace(view_count=3)
    assert ExtractSettings().replace(n_views=9).n_views == 9


@pytest.fixture(scope="module")
def tiny():
    syn = make_scene(seed=0)
    return syn, syn.reference_camera(32, 24)


def test_extract_rejects_unknown_keywords_before_any_work(tiny):
    syn, cam = tiny
    with pytest.raises(ValidationError, match=r"\['n_view'\].*valid names: .*n_views"):
        extract(syn.scene, cam, np.ones((24, 32), bool), n_view=3)
    with pytest.raises(ValidationError, match=r"n_views must be in 2\.\.360"):
        extract(syn.scene, cam, np.ones((24, 32), bool), n_views=1)
    # issue 12 items 4, 6, 7: each was a TypeError/ValueError, a silent empty selection or a hang
    for kw, match in [({"n_views": float("nan")}, "n_views must be an integer"),
                      ({"n_views": 10 ** 7}, r"n_views must be in 2\.\.360"),
                      ({"threshold": float("nan")}, "threshold must be finite"),
                      ({"threshold": 2.0}, r"threshold must be in \[0, 1\)"),
                      ({"lift_options": {"k_neighbours": 3}}, r"seed_lift has no option\(s\) \['k_neighbours'\]"),
                      ({"solver_options": {"max_iter": 10 ** 9}}, r"max_iter must be in 1\.\.100,000")]:
        with pytest.raises(ValidationError, match=match):
            extract(syn.scene, cam, np.ones((24, 32), bool), **kw)
    with pytest.raises(ValidationError, match="settings must be an ExtractSettings"):
        extract(syn.scene, cam, np.ones((24, 32), bool), settings={"n_views": 3})
    with pytest.raises(ValidationError, match="unknown solver method 'nope'"):
        extract(syn.scene, cam, np.ones((24, 32), bool), None, None, "nope")  # the old positional method


def test_extract_settings_and_overrides(tiny):
    syn, _ = tiny
    cam = syn.reference_camera(64, 48)
    truth = syn.labels == 2
    from seed2gs_inverse.raster import build_operator

    seed = (build_operator(syn.scene, cam).W @ truth.astype(np.float32)).reshape(cam.image_shape) > 0.5
    base = ExtractSettings(method="voting", n_views=3, progress=False)
    ex = extract(syn.scene, cam, seed, settings=base, n_views=4)
    assert ex.settings == base.replace(n_views=4)
    assert ex.clips.count("flat") == 4
    old = extract(syn.scene, cam, seed, None, None, "voting", n_views=4, progress=False)  # positional method
    np.testing.assert_array_equal(old.q, ex.q)
    rep = json.loads(json.dumps(ex.report()))
    assert ExtractSettings.from_dict(rep["settings"]) == ex.settings
    assert set(rep["resolved"]) == {"view_scale", "reference_scale", "up", "up_method", "up_confidence",
                                    "threshold", "solver_options", "n_weak_evidence", "n_vote_capped",
                                    "n_disconnected", "smoothness", "tracker", "seed_band", "grounder", "support",
                                    "warnings", "caps"}
    assert rep["resolved"]["caps"] == {}  # 64x48 at scale 0.5: no cap reached
    assert rep["resolved"]["warnings"] == []  # a sound extraction: nothing to warn about
    assert rep["resolved"]["smoothness"] == 1.0  # None: on with the model-free tracker
    assert rep["up"]["axis"] == rep["resolved"]["up"] and rep["up"]["method"] == rep["resolved"]["up_method"]
    assert rep["resolved"]["tracker"] == "GeometricTracker" and rep["resolved"]["grounder"] is None
    assert rep["resolved"]["threshold"] == ex.threshold and rep["resolved"]["reference_scale"] == 1.0
    assert rep["resolved"]["n_weak_evidence"] == ex.result.info["n_weak_evidence"]
    assert rep["resolved"]["n_vote_capped"] == ex.result.info["n_vote_capped"]


@pytest.mark.parametrize("name, value", [
    ("fill_radius", float("nan")), ("fill_radius", 0.0), ("fill_sigma_color", 0), ("min_support", float("nan")),
    ("min_support", 1.5), ("color_tol", -1.0), ("color_tol", float("nan")), ("max_sources", 2.5),
    ("max_sources", 0), ("boundary_band", -1), ("boundary_band", True),
])
def test_the_model_free_tracker_refuses_what_switched_its_fill_off(name, value):
    """A NaN fill radius or support and a zero colour sigma switched the 2D fill off without a word; a
    negative colour tolerance copied no label; max_sources=2.5 became 2."""
    from seed2gs_inverse.frontend.model_free import GeometricTracker

    with pytest.raises(ValidationError, match=name):
        GeometricTracker(**{name: value})
    GeometricTracker(color_tol=None, min_support=0.0, boundary_band=np.int64(2), max_sources=np.int32(3))
    assert GeometricTracker(max_sources=3.0).max_sources == 3
