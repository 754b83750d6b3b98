"""Generated tracking sequences (tactile6d.sim.sequences): motion, validity, lift-off, pose errors, the stage."""

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from tactile6d.core.config import compose_config
from tactile6d.core.errors import InputError
from tactile6d.core.geometry import invert_pose, rotation_angle, rotmat_to_rotvec
from tactile6d.core.sensor import bodies_overlap
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.data.schemas import SEQUENCE_FIELDS
from tactile6d.sim import scenes, sequences, surface_sampling
from tactile6d.sim.render import DigitRenderer
from tactile6d.sim.sequences import SequenceSpec

F = 30  # frames per test sequence: one second
SPEC = SequenceSpec(n_frames=F, candidates_per_object=300, lift_probability=1.0)


def blank(obj, T_world_object, T_world_sensors, seed):
    """A render callable whose images do not matter."""
    return np.zeros((len(T_world_sensors), 320, 240, 3), np.uint8)


@pytest.fixture(scope="module")
def objects():
    """A box and a ball a few cm across: meshes, surface samples, database points."""
    meshes = {"box": trimesh.creation.box(extents=(0.10, 0.08, 0.06)),
              "ball": trimesh.creation.icosphere(subdivisions=4, radius=0.04)}
    surfaces = {k: surface_sampling.sample_surface(m) for k, m in meshes.items()}
    rng = np.random.default_rng(0)
    database = {k: surface_sampling.sample_surface_random(m, 200, rng)[0] for k, m in meshes.items()}
    return meshes, surfaces, database


def generate(objects, spec=SPEC, n=4, seed=3, render=blank, names=("box", "ball"), progress=None):
    meshes, surfaces, database = objects
    return sequences.generate_sequences(list(names), meshes, surfaces, database, render, spec, n, seed, progress)


@pytest.fixture(scope="module")
def seqs(objects):
    return generate(objects)


def test_profiles_start_at_zero_stay_bounded_and_move_slowly():
    rng = np.random.default_rng(0)
    for _ in range(50):
        u = sequences.smooth_profile(F, rng)
        assert u[0] == 0 and np.abs(u).max() <= 1 + 1e-12
        assert np.abs(np.diff(u)).max() <= 1.5 * np.pi / (F - 1) + 1e-12
    w = sequences.lift_weights(20, start=8, length=3)  # frames 8-10 lifted, ramps of 3 frame intervals
    np.testing.assert_allclose(w[5:14], [0, 1 / 3, 2 / 3, 1, 1, 1, 2 / 3, 1 / 3, 0])
    assert w[:5].sum() == 0 and w[14:].sum() == 0


@pytest.mark.slow
def test_shapes_and_names(seqs):
    Q, L = 4, 3
    assert len(seqs) == Q and seqs.fps == 30.0
    assert sorted(set(seqs.objects)) == ["ball", "box"]  # the two objects alternate after the seed's shuffle
    assert all(n.startswith(f"{o}/sequence_") for n, o in zip(seqs.names, seqs.objects))
    assert seqs.T_world_object.shape == (Q, F, 4, 4)
    assert seqs.T_world_sensors.shape == seqs.T_world_sensors_true.shape == (Q, F, L, 4, 4)
    assert seqs.images.shape == (Q, F, L, 320, 240, 3) and seqs.images.dtype == np.uint8
    assert seqs.touching.shape == seqs.depths.shape == seqs.lift_weights.shape == (Q, F, L)
    assert seqs.touching.dtype == bool
    assert seqs.contact_points.shape == seqs.contact_normals.shape == (Q, F, L, 3)
    assert seqs.pose_bias_translation.shape == seqs.pose_bias_rotvec.shape == (Q, L, 3)
    assert set(seqs.as_datasets()) == set(SEQUENCE_FIELDS)


@pytest.mark.slow
def test_a_seed_gives_the_same_set(objects, seqs):
    again = generate(objects)
    for key, value in seqs.as_datasets().items():
        np.testing.assert_array_equal(again.as_datasets()[key], value, err_msg=key)
    other = generate(objects, seed=4)
    assert not np.allclose(other.T_world_sensors_true, seqs.T_world_sensors_true)


def test_contacts_stay_on_the_surface_and_move_smoothly(objects, seqs):
    meshes = objects[0]
    on_object = sequences.object_contacts(seqs)
    for q, obj in enumerate(seqs.objects):
        _, distance, _ = trimesh.proximity.closest_point(meshes[obj], on_object[q].reshape(-1, 3))
        assert distance.max() < 1e-6
    on_gel = sequences.gel_contacts(seqs)
    for paths in (on_object, on_gel):
        assert sequences.frame_steps(paths).max() < 0.0015  # m per frame at 30 fps
        assert sequences.path_lengths(paths).min() > 0.0002  # every contact moves
    # the contacts slide and roll by about their maxima, not more
    start = np.linalg.norm(on_object - on_object[:, :1], axis=-1).max(axis=1)
    assert start.max() <= SPEC.slide_max + 1e-6 and np.median(start) > SPEC.slide_max / 4
    assert np.abs(on_gel).max() <= SPEC.gel_travel_max + 1e-6 and np.median(np.abs(on_gel).max(axis=1)) > 0.0005
    # the touching gel point presses by the recorded depth along the sensor's axis (gel_point takes the offset
    # in the apex plane, a few um from the gel point's own y, z: the gel's x changes by < 1 um over that)
    local = np.einsum("qflji,qflj->qfli", seqs.T_world_sensors_true[..., :3, :3],
                      seqs.contact_points - seqs.T_world_sensors_true[..., :3, 3])
    gel_x = np.array([[[scenes.gel_point(*g)[0] for g in row] for row in q] for q in on_gel])
    np.testing.assert_allclose(gel_x - local[..., 0], seqs.depths, atol=2e-5)


@pytest.mark.slow
def test_every_frame_is_a_valid_grasp(objects, seqs):
    """No sensor body penetrates the object (all of its surface samples checked), no two bodies overlap."""
    surfaces = objects[1]
    T_object_sensors = invert_pose(seqs.T_world_object)[:, :, None] @ seqs.T_world_sensors_true
    for q, obj in enumerate(seqs.objects):
        for t in range(F):
            T = T_object_sensors[q, t]
            for i in range(3):
                assert not scenes.body_penetrates(surfaces[obj], T[i]), (q, t, i)
                assert not any(bodies_overlap(T[i], T[j]) for j in range(i)), (q, t, i)
    normals = invert_pose(seqs.T_world_object)[:, :, None, :3, :3] @ seqs.contact_normals[..., None]
    turns = np.degrees(np.arccos(np.clip(np.sum(normals[:, 1:] * normals[:, :-1], axis=(-2, -1)), -1, 1)))
    assert turns.max() <= SPEC.max_normal_turn_deg


@pytest.mark.slow
def test_touching_follows_the_lift_windows(objects, seqs):
    lifted = seqs.lift_weights > 0
    assert np.all(lifted.any(axis=1).sum(axis=1) == 1)  # lift_probability 1: one sensor per sequence
    assert not seqs.touching[seqs.lift_weights == 1].any()
    assert seqs.touching[seqs.lift_weights == 0].all()
    np.testing.assert_allclose(seqs.depths[seqs.lift_weights == 1], -SPEC.lift_distance)
    for q in range(len(seqs)):
        i = int(np.flatnonzero(lifted[q].any(axis=0))[0])
        off = np.flatnonzero(~seqs.touching[q, :, i])
        assert len(off) >= SPEC.lift_frames and np.all(np.diff(off) == 1)  # one window
        full = np.flatnonzero(seqs.lift_weights[q, :, i] == 1)
        assert len(full) == SPEC.lift_frames and F / 4 <= full[0] and full[-1] < 3 * F / 4
    never = generate(objects, spec=replace(SPEC, lift_probability=0.0), n=2)
    assert never.touching.all() and not never.lift_weights.any()


@pytest.mark.slow
def test_reported_poses_carry_a_constant_bias_and_a_small_jitter(objects):
    spec = replace(SPEC, lift_probability=0.0)
    out = generate(objects, spec=spec, n=6, seed=11)
    error = invert_pose(out.T_world_sensors_true) @ out.T_world_sensors  # (Q, F, L, 4, 4), sensor frame
    t_mm = 1e3 * error[..., :3, 3]
    w_deg = np.degrees(rotmat_to_rotvec(error[..., :3, :3]))
    # the bias: the error's mean over a sequence is the bias drawn, spread like the sigmas (loose bounds)
    np.testing.assert_allclose(t_mm.mean(axis=1), 1e3 * out.pose_bias_translation, atol=0.1)
    np.testing.assert_allclose(w_deg.mean(axis=1), np.degrees(out.pose_bias_rotvec), atol=0.1)
    assert 0.6 * spec.pose_sigma_mm < t_mm.mean(axis=1).std() < 1.5 * spec.pose_sigma_mm
    assert 0.6 * spec.pose_sigma_deg < w_deg.mean(axis=1).std() < 1.5 * spec.pose_sigma_deg
    # the jitter: frame to frame the error moves by about jitter only
    assert 0.6 * spec.jitter_mm < t_mm.std(axis=1).mean() < 1.5 * spec.jitter_mm
    assert 0.6 * spec.jitter_deg < w_deg.std(axis=1).mean() < 1.5 * spec.jitter_deg


@pytest.mark.slow
def test_the_hand_moves_the_whole_grasp_within_its_maxima(objects, seqs):
    shift = np.linalg.norm(seqs.T_world_object[:, :, :3, 3] - seqs.T_world_object[:, :1, :3, 3], axis=-1)
    turn = np.degrees(rotation_angle(seqs.T_world_object[:, :, :3, :3], seqs.T_world_object[:, :1, :3, :3]))
    assert shift.max() <= SPEC.hand_translation_max + 1e-9 and shift.max(axis=1).min() > 0.002
    assert turn.max() <= SPEC.hand_rotation_max_deg + 1e-6 and turn.max(axis=1).min() > 1.0
    assert shift[:, 0].max() == 0 and turn[:, 0].max() < 1e-6
    # with the hand still, the same seed gives the same grasp on the object, and an object that stays put
    still = generate(objects, spec=replace(SPEC, hand_translation_max=0.0, hand_rotation_max_deg=0.0))
    np.testing.assert_allclose(still.T_world_object, np.repeat(still.T_world_object[:, :1], F, axis=1))

    def on_object(s):
        return invert_pose(s.T_world_object)[:, :, None] @ s.T_world_sensors_true

    np.testing.assert_allclose(on_object(still), on_object(seqs), atol=1e-12)


@pytest.mark.slow
def test_a_sequence_the_renderer_refuses_is_drawn_again(objects):
    calls, frames = [], []

    def refuses_once(obj, T_world_object, T_world_sensors, seed):
        calls.append(seed)
        if len(calls) == 5:
            raise InputError("object inside the sensor body")
        return blank(obj, T_world_object, T_world_sensors, seed)

    out = generate(objects, n=1, render=refuses_once, progress=frames.append, names=("box",))
    assert len(out) == 1 and len(calls) == F + 5 and sum(frames) == F  # the 4 frames rendered were taken back

    def refuses(obj, T_world_object, T_world_sensors, seed):
        raise InputError("never")

    with pytest.raises(RuntimeError, match="box"):
        generate(objects, spec=replace(SPEC, max_tries=2), n=1, render=refuses, names=("box",))


@pytest.mark.slow
def test_rendered_frames_show_contact_exactly_where_the_sensors_touch(objects):
    """Real images over a flat grey background: a sensor that does not touch (lifted) shows the no-contact
    image with its noise, a touching one its imprint; the renderer's own mask agrees with ``touching``."""
    renderer = DigitRenderer.from_default_config(np.full((320, 240, 3), 128, np.uint8), workers=1)
    calls = []

    def render(obj, T_world_object, T_world_sensors, seed):
        out = [renderer.render(objects[0][obj], T_world_object, T, seed + i) for i, T in enumerate(T_world_sensors)]
        calls.append((seed, [r.mask.any() for r in out]))
        return np.stack([r.image for r in out])

    spec = replace(SPEC, n_frames=16, lift_seconds=0.1)
    out = generate(objects, spec=spec, n=1, render=render, names=("box",))
    seeds, masks = zip(*calls[-16:])  # the frames of the draw that was kept
    np.testing.assert_array_equal(np.array(masks), out.touching[0])
    assert (~out.touching[0]).sum() >= 3 and (out.depths[0] > 0.001).sum() >= 10
    for t, seed in enumerate(seeds):
        for i in range(3):
            no_contact = renderer.no_contact(seed + i)
            changed = np.abs(out.images[0, t, i].astype(int) - no_contact).max(axis=2) > 20
            if not out.touching[0, t, i]:
                np.testing.assert_array_equal(out.images[0, t, i], no_contact)
            elif out.depths[0, t, i] > 0.001:
                assert changed.sum() > 200, (t, i)  # pixels of the imprint


def test_the_config_section_gives_the_spec_defaults():
    from stages.make_sequences import spec_from_config

    cfg = compose_config()
    assert spec_from_config(cfg.sequences) == SequenceSpec()
    assert cfg.sequences.count == 6 and cfg.sequences.objects is None


@pytest.mark.slow
def test_a_set_survives_its_artifact(tmp_path, seqs):
    path = write_artifact(tmp_path / "tracking.h5", "sequences", seqs.as_datasets(), compression="lzf")
    back = sequences.sequence_set_from_artifact(read_artifact(path, "sequences"))
    assert back.fps == seqs.fps and back.names.tolist() == seqs.names.tolist()
    for key in SEQUENCE_FIELDS:
        if key not in ("names", "objects", "fps"):
            np.testing.assert_array_equal(getattr(back, key), getattr(seqs, key), err_msg=key)


@pytest.mark.slow
def test_the_stage_writes_the_tracking_set(tmp_path, data_dir):
    from stages import make_sequences, prepare_object, sample_surface
    from tactile6d.data import layout

    root = str(tmp_path)
    assert prepare_object.main(["--object", "prim_box", f"paths.artifacts_dir={root}", "prepare.collision=hull"]) == 0
    assert sample_surface.main(["--object", "prim_box", f"paths.artifacts_dir={root}", "sample.M=200"]) == 0
    args = [f"paths.artifacts_dir={root}", "sequences.objects=[prim_box]", "sequences.count=1", "sequences.n_frames=8"]
    assert make_sequences.main(args) == 0
    art = read_artifact(layout.sequences_file(root, "tracking"), "sequences")
    assert art["images"].shape == (1, 8, 3, 320, 240, 3) and art.config["sequences"]["seed"] == 7
    assert art.attrs["summary"]["sequences"] == 1
