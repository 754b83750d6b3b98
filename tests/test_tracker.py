"""The tracker (tactile6d.estimation.tracker) on rendered sequences of an ellipsoid held by three DIGITs.

The object is an ellipsoid of semi-axes 45, 35 and 28 mm: curved everywhere, so each image's contact patch gives a
well-defined contact (a box's flat faces press the whole gel, whose deepest point is ill-defined), and its
symmetries (half turns about its axes) all keep its centre, so the positional error below is the distance between
centres whatever symmetric pose an estimate picks. The sequences are ``sim.sequences.generate_sequences`` rendered by
the real ``DigitRenderer`` over a flat colour background, the estimator is method ``ours`` with patch contacts and
render-and-compare (the defaults) but a fake image encoder: every database angle 0 and every image read as 0, so
the tactile selection keeps every database point (the baseline's Omega_i) while the contacts are still read from
the images, which the tracker needs (which sensors touch, render-and-compare).
"""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from tactile6d.core import geometry as g
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ConfigError, InputError
from tactile6d.core.settings import Settings
from tactile6d.estimation import confidence
from tactile6d.estimation import estimator as est
from tactile6d.estimation.tracker import MODES, TrackedFrame, Tracker, TrackSettings, _Hypothesis
from tactile6d.perception.contacts import UntouchedSensorWarning
from tactile6d.sim import sequences, surface_sampling
from tactile6d.sim.render import DigitRenderer

AXES = (0.045, 0.035, 0.028)  # m, the ellipsoid's semi-axes
# The no-contact image: a flat colour (a grey one is refused as no DIGIT's), RGB. The renderer takes its
# background in OpenCV's BGR order and gives RGB images, whose noise-free no-contact image is then exactly this.
NO_CONTACT = np.broadcast_to(np.array([120, 128, 124], np.uint8), (320, 240, 3)).copy()
F = 30  # frames per sequence
# A small kinematic error on the reported sensor poses (the default is 1.5 mm / 1.5 deg) and one sensor lifted off
# for 3 frames (plus the 3-frame ramps), so that the tracker also meets frames where only two sensors touch.
SPEC = sequences.SequenceSpec(n_frames=F, candidates_per_object=300, pose_sigma_mm=0.5, pose_sigma_deg=0.5,
                              jitter_mm=0.05, jitter_deg=0.05, lift_probability=1.0, lift_seconds=0.1)
SEED = 2  # sequence 0 of this seed: a grasp whose contacts fix the ellipsoid's position to about 1 mm
OVERRIDES = ["select.N=500"]
BACK_5MM = g.make_pose(np.eye(3), [-0.005, 0.0, 0.0])  # a sensor moved 5 mm back, away from the object (-x)


def ellipsoid() -> trimesh.Trimesh:
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    mesh.apply_scale(AXES)
    return mesh


@pytest.fixture(scope="module")
def world():
    """The ellipsoid, its surface samples, 600 database points, the renderer and two rendered sequences."""
    mesh = ellipsoid()
    surface = surface_sampling.sample_surface(mesh)
    points, normals, _ = surface_sampling.sample_surface_even(mesh, 600, np.random.default_rng(0))
    renderer = DigitRenderer.from_default_config(np.ascontiguousarray(NO_CONTACT[..., ::-1]), workers=1)

    def render(obj, T_world_object, T_world_sensors, seed):
        return np.stack([renderer.render(mesh, T_world_object, T, seed + i).image
                         for i, T in enumerate(T_world_sensors)])

    seqs = sequences.generate_sequences(["ellipsoid"], {"ellipsoid": mesh}, {"ellipsoid": surface},
                                        {"ellipsoid": points}, render, SPEC, 2, SEED)
    return {"mesh": mesh, "surface": surface, "points": points, "normals": normals, "renderer": renderer,
            "seqs": seqs}


def make_estimator(world, *overrides) -> est.Estimator:
    from test_estimator import small_patch_model

    settings = Settings.from_cfg(compose_config(OVERRIDES + list(overrides)))
    return est.Estimator(world["points"], [world["mesh"].vertices], np.zeros(len(world["points"])),
                         encoder=lambda images, *backgrounds: np.zeros(len(images)), settings=settings,
                         normals=world["normals"], surface=world["surface"], no_contact=NO_CONTACT,
                         patch_model=small_patch_model(), mesh=world["mesh"])


@pytest.fixture(scope="module")
def estimator(world):
    return make_estimator(world)


def track_settings(**changes) -> TrackSettings:
    return replace(TrackSettings.from_cfg(compose_config(OVERRIDES).track), **changes)


def position_error(frame: TrackedFrame, T_true: np.ndarray) -> float:
    """m, between the tracked and the true centre (the ellipsoid's symmetries keep it)."""
    return float(np.linalg.norm(frame.pose[:3, 3] - T_true[:3, 3]))


def run(tracker, T_world_sensors, images, **kwargs) -> list[TrackedFrame]:
    return [tracker.update(T, im, **kwargs) for T, im in zip(T_world_sensors, images)]


@pytest.fixture(scope="module")
def tracked(world, estimator):
    """Sequence 0 tracked with the default track settings."""
    seqs = world["seqs"]
    with Tracker(estimator, track_settings()) as tracker:
        frames = run(tracker, seqs.T_world_sensors[0], seqs.images[0])
        last = tracker.pose
    return frames, last


@pytest.mark.slow
def test_a_sequence_is_tracked_within_5_mm(world, tracked):
    """Measured on this sequence: the tracked centre is 0.4-1.2 mm from the true one on every frame (single-shot
    estimates of every third frame: 0.7-3.4 mm). 5 mm leaves room for the tracker's tuning and still catches a
    track that drifts along the surface: on other grasps of this ellipsoid (other seeds) the updates drift 7-11 mm
    away while the single-shot estimates of their re-detected frames stay within 1.5-4.3 mm. That drift is each
    frame's own optimum under the sensor-pose error the estimator allows (the default 1.5 mm and 1.5 deg, against
    SPEC's 0.5): declared as SPEC's, seed 9's first sequence is followed at 0.7 mm median against 5.8
    (docs/journal.md, 2026-12-06)."""
    frames, last = tracked
    seqs = world["seqs"]
    assert frames[0].mode == "redetect" and frames[0].reason == "start" and frames[0].fit_ok
    assert frames[0].estimate is not None and np.array_equal(frames[0].pose, frames[0].estimate.best)
    assert all(f.mode in MODES for f in frames)
    later = [f.mode for f in frames[1:]]
    assert later.count("update") >= 2 * len(later) / 3, later
    assert "hold" not in later and all(f.reason != "start" for f in frames[1:])
    check = track_settings()
    for f in frames:
        if f.mode == "update":  # passed the fit check
            assert f.reason is None and f.estimate is None and f.fit_ok
            assert 0 <= f.residual <= check.max_residual and 0 <= f.agreement <= check.max_agreement
    errors = np.array([position_error(f, T) for f, T in zip(frames, seqs.T_world_object[0])])
    assert errors.max() < 0.005, np.round(1e3 * errors, 2)
    for f in frames:
        assert g.is_rotation(f.pose[:3, :3]) and np.array_equal(f.pose[3], [0, 0, 0, 1])
    np.testing.assert_array_equal(last, frames[-1].pose)


@pytest.mark.slow
def test_touching_is_what_the_images_show(world, tracked):
    """While one sensor is lifted (3 mm off, its image the no-contact one) only the two others touch; on the
    lift's ramps the gel may still be pressed a few um, which no image shows, so those frames are left out."""
    frames, _ = tracked
    seqs = world["seqs"]
    clear = np.all((seqs.lift_weights[0] == 0) | (seqs.lift_weights[0] == 1), axis=1)
    touching = np.array([f.touching for f in frames])
    assert touching.shape == (F, 3) and touching.dtype == bool
    np.testing.assert_array_equal(touching[clear], seqs.touching[0][clear])
    lifted = np.flatnonzero((seqs.lift_weights[0] == 1).any(axis=1))
    assert len(lifted) == 3 and clear[lifted].all()
    # the track goes on through the lift, the lifted sensor left out of the fit
    assert any(frames[t].mode == "update" for t in lifted), [frames[t].mode for t in lifted]


@pytest.mark.slow
def test_a_frame_with_a_lifted_sensor_is_estimated_from_the_two_that_touch(world, estimator):
    """Single-shot, the lifted sensor (3 mm off, its image the no-contact one) is left out of selection and fit:
    1.1-1.7 mm from the true centre on both sequences' lifted frames. Its landmark taken for a contact, as before,
    put the estimates 3.0-6.9 mm off."""
    seqs = world["seqs"]
    for q in range(2):
        lifted = np.flatnonzero((seqs.lift_weights[q] == 1).any(axis=1))
        assert len(lifted) == 3
        for t in lifted:
            off = int(np.flatnonzero(seqs.lift_weights[q, t] == 1)[0])
            with pytest.warns(UntouchedSensorWarning, match=f"sensor\\(s\\) {off}:"):
                result = estimator.estimate(seqs.T_world_sensors[q, t], seqs.images[q, t])
            assert not result.contacts.touching[off] and result.contacts.touching.sum() == 2
            assert (result.selection.tuples[:, off] == -1).all() and (result.selection.tuples[:, result.contacts.touching] >= 0).all()
            error = np.linalg.norm(result.best[:3, 3] - seqs.T_world_object[q, t, :3, 3])
            assert error < 0.0025, (q, t, error)


@pytest.mark.slow
def test_re_detections_wait_while_a_sensor_is_lifted(world, estimator):
    """No hypothesis passes a render-and-compare check of 0, so every frame asks for a re-detection; while the
    lifted sensor shows no contact, the contacts still fitting, the last pose is held instead (reason ``lift``,
    hypotheses kept), up to ``lift_wait`` frames; with ``lift_wait`` 0 those frames are estimated from the two
    sensors that touch. (A swap, whose contacts fit nothing, is re-detected at once: the next test.)"""
    seqs = world["seqs"]
    T, images = seqs.T_world_sensors[0, :24], seqs.images[0, :24]
    for wait in (30, 0):
        with Tracker(estimator, track_settings(max_agreement=0.0, lift_wait=wait)) as tracker:
            frames = run(tracker, T, images)
        lifted = np.array([not f.touching.all() for f in frames])
        assert lifted.sum() >= 3 and not lifted[0], lifted
        for t, f in enumerate(frames[1:], start=1):
            if lifted[t] and wait:
                assert (f.mode, f.reason, f.fit_ok) == ("hold", "lift", False), (t, f.mode, f.reason)
                np.testing.assert_array_equal(f.pose, frames[t - 1].pose)
            else:
                assert (f.mode, f.reason, f.fit_ok) == ("redetect", "fit", True), (t, f.mode, f.reason)


@pytest.mark.slow
def test_a_periodic_re_detection_waits_until_the_lifted_sensor_touches_again(world, estimator):
    seqs = world["seqs"]
    with Tracker(estimator, track_settings(redetect_every=1)) as tracker:
        frames = run(tracker, seqs.T_world_sensors[0, :24], seqs.images[0, :24])
    lifted = np.array([not f.touching.all() for f in frames])
    assert lifted.sum() >= 3
    assert all(f.mode == "update" for f, up in zip(frames, lifted) if up), [f.mode for f in frames]
    after = int(np.flatnonzero(lifted)[-1]) + 1  # the first frame the sensor touches again: the period has passed
    assert (frames[after].mode, frames[after].reason) == ("redetect", "periodic")


@pytest.mark.slow
def test_a_3_cm_jump_is_re_detected_and_recovered(world, estimator):
    """The whole grasp, object and sensors, jumps 3 cm in the world after frame 9 (the images stay the same):
    the last pose no longer fits the contacts, the frame is re-detected, and the track is back within 1 cm."""
    seqs = world["seqs"]
    jump, shift = 10, g.make_pose(np.eye(3), [0.03, 0.0, 0.0])
    moves = np.stack([shift if t >= jump else np.eye(4) for t in range(20)])
    T_true = moves @ seqs.T_world_object[0, :20]
    with Tracker(estimator, track_settings()) as tracker:
        frames = run(tracker, moves[:, None] @ seqs.T_world_sensors[0, :20], seqs.images[0, :20])
    errors = np.array([position_error(f, T) for f, T in zip(frames, T_true)])
    assert errors[:jump].max() < 0.005
    assert any(f.mode == "redetect" and f.reason == "fit" for f in frames[jump:jump + 3]), \
        [(f.mode, f.reason) for f in frames[jump:]]
    assert errors[jump:jump + 6].min() < 0.01 and errors[jump + 5:].max() < 0.01, np.round(1e3 * errors, 1)


@pytest.mark.slow
def test_another_grasp_of_the_object_is_recovered(world, estimator):
    """The stream switches to another sequence (the object elsewhere, in another grasp) at frame 10."""
    seqs = world["seqs"]
    swap = 10
    q = np.array([0] * swap + [1] * 10)
    t = np.arange(20)
    with Tracker(estimator, track_settings()) as tracker:
        frames = run(tracker, seqs.T_world_sensors[q, t], seqs.images[q, t])
    errors = np.array([position_error(f, T) for f, T in zip(frames, seqs.T_world_object[q, t])])
    far = np.linalg.norm(seqs.T_world_object[1, swap, :3, 3] - seqs.T_world_object[0, swap - 1, :3, 3])
    assert far > 0.02  # the object is elsewhere indeed
    assert any(f.mode == "redetect" and f.reason == "fit" for f in frames[swap:swap + 3]), \
        [(f.mode, f.reason) for f in frames[swap:]]
    assert errors[swap:swap + 6].min() < 0.01 and errors[swap + 5:].max() < 0.01, np.round(1e3 * errors, 1)


def lifted_frame(world, q: int, t: int):
    """Frame t of sequence q with every sensor moved 5 mm back from the object, rendered: (reported poses,
    images); the renderer's own masks show no contact."""
    seqs, renderer = world["seqs"], world["renderer"]
    results = [renderer.render(world["mesh"], seqs.T_world_object[q, t], T @ BACK_5MM, seed=100 + i)
               for i, T in enumerate(seqs.T_world_sensors_true[q, t])]
    assert not any(r.mask.any() for r in results)
    return seqs.T_world_sensors[q, t] @ BACK_5MM, np.stack([r.image for r in results])


@pytest.mark.slow
def test_a_frame_without_contact_holds_the_pose(world, estimator):
    seqs = world["seqs"]
    T_lifted, images_lifted = lifted_frame(world, 0, 8)
    with Tracker(estimator, track_settings()) as tracker:
        before = run(tracker, seqs.T_world_sensors[0, :8], seqs.images[0, :8])
        held = tracker.update(T_lifted, images_lifted)
        assert np.array_equal(tracker.pose, before[-1].pose)
        after = run(tracker, seqs.T_world_sensors[0, 9:12], seqs.images[0, 9:12])
    assert held.mode == "hold" and held.reason is None and held.estimate is None
    assert held.touching.tolist() == [False, False, False]
    np.testing.assert_array_equal(held.pose, before[-1].pose)
    assert np.isnan([held.residual, held.agreement, held.penetration]).all()
    # the track goes on from the held pose: updated, not re-detected, and still within 5 mm
    assert after[0].mode == "update" and after[0].touching.all()
    errors = [position_error(f, T) for f, T in zip(after, seqs.T_world_object[0, 9:12])]
    assert max(errors) < 0.005, errors


@pytest.mark.slow
def test_no_pose_before_any_contact(world, estimator):
    """A stream that starts with the sensors lifted has nothing to estimate from: no pose (NaN) until a frame
    shows contact (TrackedFrame: pose NaN before any pose was found; a frame without contact holds)."""
    seqs = world["seqs"]
    T_lifted, images_lifted = lifted_frame(world, 0, 0)
    with Tracker(estimator, track_settings()) as tracker:
        first = tracker.update(T_lifted, images_lifted)
        then = tracker.update(seqs.T_world_sensors[0, 1], seqs.images[0, 1])
    assert first.touching.tolist() == [False, False, False]
    assert first.mode == "hold" and np.isnan(first.pose).all()
    assert then.mode == "redetect" and then.reason == "start"


@pytest.mark.slow
def test_requested_re_detection_and_reset(world, estimator):
    seqs = world["seqs"]
    T, images = seqs.T_world_sensors[0], seqs.images[0]
    with Tracker(estimator, track_settings(redetect_every=0)) as tracker:
        frames = run(tracker, T[:4], images[:4])
        requested = tracker.update(T[4], images[4], redetect=True)
        following = tracker.update(T[5], images[5])
        tracker.reset()
        assert tracker.pose is None
        restarted = tracker.update(T[6], images[6])
        again = tracker.update(T[7], images[7])
    assert [f.mode for f in frames] == ["redetect", "update", "update", "update"]
    assert requested.mode == "redetect" and requested.reason == "request" and requested.estimate is not None
    assert following.mode == "update" and following.reason is None
    assert restarted.mode == "redetect" and restarted.reason == "start"
    assert again.mode == "update"
    # the re-detection after reset starts afresh: its pose is the frame's own single-shot best
    np.testing.assert_array_equal(restarted.pose, restarted.estimate.best)
    for f, t in ((requested, 4), (following, 5), (restarted, 6), (again, 7)):
        assert position_error(f, seqs.T_world_object[0, t]) < 0.005


def re_detection_gaps(frames: list[TrackedFrame]) -> list[tuple[int, int, str]]:
    """(frame, frames since the last re-detection before it, its reason) of every re-detected frame after the first."""
    out, last = [], 0
    for k, f in enumerate(frames[1:], start=1):
        if f.mode == "redetect":
            out.append((k, k - last, f.reason))
            last = k
    return out


@pytest.mark.slow
def test_redetect_every_n_re_detects_every_nth_frame(world, estimator):
    """track.redetect_every: 'the frame is also estimated from scratch this often': with 4, frames 4, 8, 12, at a
    fixed period that no frame goes longer without; with 0, never periodically."""
    seqs = world["seqs"]
    with Tracker(estimator, track_settings(redetect_every=4)) as tracker:
        frames = run(tracker, seqs.T_world_sensors[0, :14], seqs.images[0, :14])
    gaps = re_detection_gaps(frames)
    periodic = [gap for _, gap, reason in gaps if reason == "periodic"]
    assert len(periodic) >= 2, gaps
    assert len(set(periodic)) == 1, gaps  # a fixed period
    assert periodic == [4] * len(periodic), gaps
    assert all(gap <= periodic[0] for _, gap, _ in gaps), gaps  # no frame goes longer without one
    with Tracker(estimator, track_settings(redetect_every=0)) as tracker:
        frames = run(tracker, seqs.T_world_sensors[0, :14], seqs.images[0, :14])
    assert not any(f.reason == "periodic" for f in frames)


@pytest.mark.parametrize("light_every", [4, 0])
@pytest.mark.slow
def test_a_re_detection_is_the_single_shot_estimate_of_the_frame_as_given(world, estimator, light_every):
    """A re-detected frame is estimated as ``Estimator.estimate`` estimates its images as given: whether the
    tracker fitted that frame's light itself and hands its reading on (light_every = redetect_every) or not
    (light_every 0: fitted at re-detection only), and never on images already brought to their light."""
    seqs = world["seqs"]
    # LEDs drifted since the no-contact image: each channel's gain off, so that bringing the light back changes
    # the pixels (and bringing it back twice would change them again).
    images = np.clip(seqs.images[0, :13] * np.array([1.07, 0.94, 1.03]), 0, 255).astype(np.uint8)
    with Tracker(estimator, track_settings(redetect_every=4, light_every=light_every)) as tracker:
        frames = run(tracker, seqs.T_world_sensors[0, :13], images)
    periodic = [k for k, f in enumerate(frames) if f.reason == "periodic"]
    assert len(periodic) >= 2, [f.reason for f in frames]
    for k in [0] + periodic:
        alone = estimator.estimate(seqs.T_world_sensors[0, k], images[k])
        np.testing.assert_array_equal(frames[k].estimate.poses, alone.poses, err_msg=str(k))
        np.testing.assert_array_equal(frames[k].estimate.scores, alone.scores, err_msg=str(k))
        assert frames[k].estimate.light is not None and len(frames[k].estimate.light) == 3


@pytest.mark.slow
def test_a_frame_is_ambiguous_when_a_far_pose_followed_has_about_the_same_evidence(world):
    """The single-shot rule on the poses followed: another pose more than 0.75 cm (ADI) away whose evidence is
    within the confidence model's ambiguity_ratio (25 % here) of the reported one's. Those poses are the
    frame's rivals, the least evidence first; the frame is ambiguous when it has any."""
    estimator = make_estimator(world)
    estimator.confidence_model = confidence.ConfidenceModel(confidence.FEATURES, (0.0, 0.0), 0.0, (0.0, 0.0),
                                                            (1.0, 1.0), ambiguity_ratio=0.25)
    T = g.make_pose(np.eye(3), [0.3, 0.0, 0.1])
    far, near = T @ g.make_pose(np.eye(3), [0.02, 0.0, 0.0]), T @ g.make_pose(np.eye(3), [0.002, 0.0, 0.0])
    farther = T @ g.make_pose(np.eye(3), [0.0, 0.03, 0.0])
    with Tracker(estimator, track_settings()) as tracker:
        def rivals(*followed):
            tracker._hypotheses = [_Hypothesis([pose], evidence) for pose, evidence in followed]
            return tracker._rival_poses()

        def same(poses, expected):
            return poses.shape == (len(expected), 4, 4) and all(np.array_equal(p, e) for p, e in zip(poses, expected))

        assert same(rivals((T, 1.0e-3), (far, 1.2e-3)), [far])  # 2 cm away, 20 % worse: about as good
        assert same(rivals((far, 1.2e-3), (T, 1.0e-3)), [far])  # whichever order they are followed in
        assert same(rivals((T, 1.0e-3), (farther, 1.1e-3), (far, 1.2e-3)), [farther, far])  # the least evidence first
        assert same(rivals((far, 1.0e-3), (T, 1.2e-3)), [T])  # the leader is the one with the least evidence
        assert same(rivals((T, 1.0e-3), (far, 1.4e-3)), [])  # 40 % worse
        assert same(rivals((T, 1.0e-3), (near, 1.0e-3)), [])  # as good, but 2 mm away: the same pose
        assert same(rivals((T, 1.0e-3)), [])
        tracker._hypotheses = [_Hypothesis([T], 1.0e-3), _Hypothesis([far], 1.2e-3)]
        tracker._rivals = tracker._rival_poses()  # as an update or a re-detection sets them
        frame = tracker._answer(T, "update", None, np.ones(3, bool), 0.0, 0.0, 0.0, True, 0.0)
        assert frame.ambiguous and same(frame.rivals, [far]) and frame.to_dict()["rivals"] == [far.tolist()]
        estimator.confidence_model = None  # without a model, as Estimate.ambiguous: never
        assert same(rivals((T, 1.0e-3), (far, 1.0e-3)), [])


@pytest.mark.slow
def test_a_re_detection_offers_the_poses_its_rival_ratio_admits(world):
    """What a re-detection gives the tracker to follow: ``Estimate.distinct`` (the confidence model's
    ambiguity_ratio) by default; with ``track.rival_ratio`` the best and every pose more than 0.75 cm (ADI) away
    whose score is within that ratio of the best's."""
    estimator = make_estimator(world)
    T = g.make_pose(np.eye(3), [0.3, 0.0, 0.1])
    near = T @ g.make_pose(np.eye(3), [0.002, 0.0, 0.0])
    far, farther = T @ g.make_pose(np.eye(3), [0.02, 0.0, 0.0]), T @ g.make_pose(np.eye(3), [0.0, 0.03, 0.0])
    ranked = SimpleNamespace(poses=np.stack([T, near, far, farther]), scores=np.array([1.0, 1.0, 1.2, 1.4]) * 1e-3,
                             distinct=np.array([0, 2]))
    for rival_ratio, followed in ((None, [0, 2]), (0.1, [0]), (0.3, [0, 2]), (0.5, [0, 2, 3])):
        with Tracker(estimator, track_settings(rival_ratio=rival_ratio)) as tracker:
            assert [int(i) for i in tracker._to_follow(ranked)] == followed, rival_ratio
    with Tracker(estimator, track_settings()) as tracker:  # no confidence model, no rival ratio: the best alone
        assert tracker._to_follow(SimpleNamespace(poses=ranked.poses, scores=ranked.scores, distinct=None)) == [0]


@pytest.mark.slow
def test_each_frame_says_whether_it_is_ambiguous(tracked):
    frames, _ = tracked
    assert all(f.ambiguous is False and f.rivals.shape == (0, 4, 4) for f in frames)  # no confidence model here
    assert frames[0].to_dict()["ambiguous"] is False and frames[0].to_dict()["rivals"] == []


@pytest.mark.slow
def test_an_update_never_penetrates_a_sensor_beyond_the_limit(world):
    """Sensor poses off by 3 mm / 3 deg per axis (twice a hand's default), an estimator that expects 0.5 mm /
    0.5 deg and no margin: updated poses press into the sensors. Each update stays within the limit the last
    re-detection set, max(the ranking's allowance, its best pose's deepest penetration) + penetration_margin;
    with the margin at 1 m, the same frames are updated deeper than that, so the check is what keeps them out."""
    seqs = world["seqs"]
    # The contact normals in the refinement beside the patch points, which weigh as much as the contact point (not
    # the defaults since 2026-12-06, which press these sensors no deeper than the limit even without the check),
    # make updates press in.
    estimator = make_estimator(world, "sensors.pose_sigma_mm=0.5", "sensors.pose_sigma_deg=0.5",
                               "rank.refine_patch_normal_weight=0.01", "rank.refine_patch_weight=1")
    allowance = estimator.settings.sensors.contact_sigma
    spec = replace(SPEC, pose_sigma_mm=3.0, pose_sigma_deg=3.0, jitter_mm=0.1, jitter_deg=0.1)
    errors, _, _ = sequences.kinematic_errors(spec, np.random.default_rng(5))
    T = (seqs.T_world_sensors_true[0] @ errors)[:20]

    def track_with(margin):
        """The frames tracked with this margin, and each one's limit before the margin."""
        with Tracker(estimator, track_settings(penetration_margin=margin)) as tracker:
            frames = run(tracker, T, seqs.images[0, :20])
        limits, limit = [], np.inf
        for f in frames:
            if f.mode == "redetect":
                limit = max(allowance, float(f.estimate.penetrations[0].max()))
                assert f.penetration == pytest.approx(f.estimate.penetrations[0].max())
            limits.append(limit)
        updates = np.array([f.mode == "update" for f in frames])
        return updates, np.array([f.penetration for f in frames]), np.array(limits)

    updates, depths, limits = track_with(0.0)
    assert updates.sum() >= 2
    assert np.all(depths[updates] <= limits[updates]), np.round(1e3 * np.stack([depths, limits]), 2)
    updates, depths, limits = track_with(1.0)
    assert np.any(depths[updates] > limits[updates]), np.round(1e3 * np.stack([depths, limits]), 2)


@pytest.mark.slow
def test_settings_from_the_config():
    cfg = compose_config()
    settings = TrackSettings.from_cfg(cfg.track)
    kinds = {"int": (int,), "float": (int, float), "bool": (bool,), "float | None": (int, float, type(None))}
    for name, spec in TrackSettings.__dataclass_fields__.items():  # the types declared
        value = getattr(settings, name)
        assert isinstance(value, kinds[spec.type]) and (spec.type == "bool") == isinstance(value, bool), name
    assert settings.hypotheses >= 1 and settings.evidence_frames >= 1 and settings.threads >= 1
    assert settings.max_residual > 0 and settings.max_agreement > 0 and settings.penetration_margin >= 0
    assert TrackSettings.from_cfg(compose_config(["track.hypotheses=1"]).track).hypotheses == 1
    section = {k: v for k, v in cfg.track.items() if k != "max_agreement"}
    with pytest.raises(ConfigError, match=r"track lacks keys \['max_agreement'\]"):
        TrackSettings.from_cfg(section)


@pytest.mark.parametrize("key,value", [("hypotheses", 0), ("evidence_frames", 0), ("refine_iterations", 0),
                                       ("threads", 0), ("max_residual", -0.001), ("max_agreement", -1.0),
                                       ("penetration_margin", -0.001), ("redetect_every", -1), ("light_every", -1),
                                       ("lift_wait", -1), ("read_ahead", -1), ("rival_ratio", -0.1)])
@pytest.mark.slow
def test_bad_settings_are_refused(key, value):
    with pytest.raises(ConfigError, match=key):
        TrackSettings.from_cfg(compose_config([f"track.{key}={value}"]).track)


@pytest.mark.slow
def test_a_tracker_needs_the_refinement(world, estimator):
    unrefined = estimator.with_settings(Settings.from_cfg(compose_config(OVERRIDES + ["rank.refine=false"])))
    with pytest.raises(InputError, match="rank.refine"):
        Tracker(unrefined)
    with Tracker(estimator) as tracker:  # without settings: conf/'s
        assert tracker.settings == TrackSettings.from_cfg(compose_config().track)


def same_answers(a: list[TrackedFrame], b: list[TrackedFrame]) -> None:
    """Every field of two runs' answers equal, bit for bit, but the seconds."""
    assert len(a) == len(b)
    for k, (x, y) in enumerate(zip(a, b)):
        for name in TrackedFrame.__dataclass_fields__:
            if name in ("seconds", "estimate"):
                continue
            np.testing.assert_array_equal(getattr(x, name), getattr(y, name), err_msg=f"frame {k}: {name}")
        assert (x.estimate is None) == (y.estimate is None), k
        if x.estimate is not None:
            np.testing.assert_array_equal(x.estimate.poses, y.estimate.poses, err_msg=str(k))


def a_stream(world, n_frames=20):
    """Sequence 0 under drifted LEDs (so that light fits change the images), sensor 2 left out on frames 9-11
    (L = 2 there: the light is fitted anew), as (T_world_sensors, images) frames."""
    seqs = world["seqs"]
    images = np.clip(seqs.images[0, :n_frames] * np.array([1.07, 0.94, 1.03]), 0, 255).astype(np.uint8)
    T = seqs.T_world_sensors[0, :n_frames]
    return [(T[k, :2], images[k, :2]) if 9 <= k <= 11 else (T[k], images[k]) for k in range(n_frames)]


@pytest.mark.parametrize("read_ahead", [2, 0])
@pytest.mark.slow
def test_tracking_a_stream_gives_the_answers_of_update_frame_by_frame(world, estimator, read_ahead):
    """Tracker.track reads each frame's patches in reader processes while the frame before is followed: the same
    answers as update(), bit for bit, through periodic re-detections (which refit the light and make the frame
    after's reading, made under the old light, be read again), light fits every few frames and a change of L."""
    stream = a_stream(world)
    settings = track_settings(redetect_every=4, light_every=3, read_ahead=read_ahead)
    with Tracker(estimator, settings) as tracker:
        one_by_one = [tracker.update(T, images) for T, images in stream]
    with Tracker(estimator, settings) as tracker:
        tracked = list(tracker.track(iter(stream)))
        assert (tracker._reader is not None) == (read_ahead > 0)
    assert tracker._reader is None  # its own reader closed with it
    modes = [f.mode for f in one_by_one]
    assert modes.count("redetect") >= 4 and modes.count("update") >= 10, modes
    same_answers(tracked, one_by_one)


@pytest.mark.slow
def test_a_reader_serves_several_trackers_and_frames_may_carry_their_backgrounds(world, estimator):
    from tactile6d.perception.patch_reader import PatchReader

    stream = a_stream(world, 8)
    settings = track_settings(read_ahead=0)
    with Tracker(estimator, settings) as tracker:
        expected = [tracker.update(T, images, NO_CONTACT) for T, images in stream]
    with PatchReader(1) as reader:
        for _ in range(2):
            with Tracker(estimator, settings, reader) as tracker:
                same_answers(list(tracker.track((T, images, NO_CONTACT) for T, images in stream)), expected)
        assert reader._pool is not None  # the caller's reader stays open for the next tracker


@pytest.mark.slow
def test_a_bad_frame_in_a_stream_is_raised_after_the_frame_before_is_answered(world, estimator):
    stream = a_stream(world, 4)
    bad = (stream[3][0], stream[3][1][..., 0])  # grayscale planes, not RGB images
    answers = []
    with Tracker(estimator, track_settings()) as tracker:
        with pytest.raises(InputError):
            for answer in tracker.track(stream[:3] + [bad]):
                answers.append(answer)
        assert len(answers) == 3
        with pytest.raises(InputError, match="frames"):
            next(tracker.track([stream[0][0]]))
