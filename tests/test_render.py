"""The DIGIT simulator: geometry of the imprint, orientation, noise, bad input. Fast and deterministic."""

import warnings

import numpy as np
import pytest
import trimesh

from tactile6d.core import geometry as g
from tactile6d.core import sensor
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ConfigError, InputError, MeshError
from tactile6d.sim.render import CAMERA_POSITION, DigitRenderer, gel_surface, mesh_arrays, pixel_rays

H, W = sensor.IMAGE_HEIGHT, sensor.IMAGE_WIDTH
IDENTITY = np.eye(4)


@pytest.fixture(scope="module")
def background():
    """A smooth synthetic BGR background (the real one is data, not needed here)."""
    rows, cols = np.mgrid[0:H, 0:W]
    return np.stack([90 + cols // 8, 100 + rows // 10, 110 + 0 * rows], axis=-1).astype(np.uint8)


@pytest.fixture(scope="module")
def renderer(background):
    return DigitRenderer.from_default_config(background)


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(subdivisions=4, radius=0.015)


@pytest.fixture(scope="module")
def cube():
    return trimesh.creation.box(extents=(0.04, 0.04, 0.04))


def touching(point, normal, roll=0.0, depth=0.0015):
    """T_object_sensor pressing the gel ``depth`` into the surface at ``point`` with outward ``normal``."""
    return sensor.sensor_poses_touching(np.asarray(point, float), np.asarray(normal, float), roll, depth)


def principal_axes(mask):
    """(aspect ratio minor/major, angle of the major axis in degrees from the image's row axis, [0, 180))."""
    rows, cols = np.nonzero(mask)
    cov = np.cov(np.stack([rows, cols]).astype(float))
    values, vectors = np.linalg.eigh(cov)
    major = vectors[:, 1]
    angle = np.degrees(np.arctan2(major[1], major[0])) % 180.0
    return np.sqrt(values[0] / values[1]), angle


def test_no_contact_is_the_background_plus_noise(renderer, sphere):
    far = g.make_pose(np.eye(3), [0.0, 0.0, 0.3])
    result = renderer.render(sphere, IDENTITY, far, seed=3)
    assert result.image.shape == (H, W, 3) and result.image.dtype == np.uint8
    assert not result.mask.any() and not result.depth.any()
    np.testing.assert_array_equal(result.image, renderer.no_contact(seed=3))
    # noise std 7 around the background (flipped to RGB)
    residual = result.image.astype(float) - renderer.background
    assert abs(residual.mean()) < 1.0 and 6.0 < residual.std() < 8.0


def test_noise_free_no_contact_is_exactly_the_rgb_background(background):
    quiet = DigitRenderer.from_default_config(background, noise_std=0.0)
    np.testing.assert_array_equal(quiet.no_contact(seed=0), background[..., ::-1])


def test_same_seed_same_image_other_seed_other_noise(renderer, sphere):
    T = touching([0.015, 0, 0], [1, 0, 0])
    a = renderer.render(sphere, IDENTITY, T, seed=7).image
    b = renderer.render(sphere, IDENTITY, T, seed=7).image
    c = renderer.render(sphere, IDENTITY, T, seed=8).image
    np.testing.assert_array_equal(a, b)
    assert np.any(a != c)


def test_deeper_press_gives_a_larger_deeper_imprint(renderer, sphere):
    shallow = renderer.render(sphere, IDENTITY, touching([0.015, 0, 0], [1, 0, 0], depth=0.0008), seed=0)
    deep = renderer.render(sphere, IDENTITY, touching([0.015, 0, 0], [1, 0, 0], depth=0.002), seed=0)
    assert 0 < shallow.mask.sum() < deep.mask.sum()
    assert deep.depth.max() == pytest.approx(0.002, abs=2e-4)
    assert shallow.depth.max() == pytest.approx(0.0008, abs=2e-4)


def test_sphere_gives_a_round_patch_at_the_image_centre(renderer, sphere):
    result = renderer.render(sphere, IDENTITY, touching([0.015, 0, 0], [1, 0, 0], depth=0.0015), seed=0)
    aspect, _ = principal_axes(result.mask)
    assert aspect > 0.9
    rows, cols = np.nonzero(result.mask)
    # the gel apex is on the optical axis: the patch is centred
    assert abs(rows.mean() - H / 2) < 4 and abs(cols.mean() - W / 2) < 4


def test_box_edge_gives_an_elongated_patch_that_turns_with_the_roll(renderer, cube):
    edge_point = [0.02, 0.02, 0.0]  # midpoint of the cube edge parallel to z
    bisector = [1.0, 1.0, 0.0]
    r0 = renderer.render(cube, IDENTITY, touching(edge_point, bisector, roll=0.0), seed=0)
    r90 = renderer.render(cube, IDENTITY, touching(edge_point, bisector, roll=np.pi / 2), seed=0)
    aspect0, angle0 = principal_axes(r0.mask)
    aspect90, angle90 = principal_axes(r90.mask)
    assert aspect0 < 0.5 and aspect90 < 0.5
    # At roll 0 the sensor z axis is the world z axis (sensor_poses_touching's rule), i.e. along the
    # edge, and image rows run along sensor z: the patch is vertical. A quarter roll makes it horizontal.
    assert min(angle0, 180 - angle0) < 10
    assert abs(angle90 - 90) < 10


def test_image_orientation_rows_along_minus_z_columns_along_minus_y(renderer, sphere):
    """A contact at +z in the sensor frame shows in the top half; at +y in the left half."""
    radius = 0.015
    press = 0.0015
    for offset, check in [
        ([0.0, 0.0, 0.005], lambda rows, cols: rows.mean() < H / 2 - 20),
        ([0.0, 0.005, 0.0], lambda rows, cols: cols.mean() < W / 2 - 20),
    ]:
        # sphere centre straight ahead of the (sagged) gel point at that offset
        gel_x = sensor.GEL_CENTER[0] - 0.0002
        centre = np.array([gel_x + radius - press, 0.0, sensor.GEL_CENTER[2]]) + offset
        result = renderer.render(sphere, g.make_pose(np.eye(3), centre), IDENTITY, seed=0)
        rows, cols = np.nonzero(result.mask)
        assert len(rows) > 100 and check(rows, cols)


def test_red_light_side_is_brighter_in_the_red_channel(background, sphere):
    """The red light sits at +y, +z: a sphere's slope facing it (top left of the image) turns red."""
    quiet = DigitRenderer.from_default_config(background, noise_std=0.0)
    result = quiet.render(sphere, IDENTITY, touching([0.015, 0, 0], [1, 0, 0], depth=0.002), seed=0)
    diff = result.image.astype(float) - quiet.background
    top_left = diff[: H // 2, : W // 2][result.mask[: H // 2, : W // 2]]
    bottom_right = diff[H // 2 :, W // 2 :][result.mask[H // 2 :, W // 2 :]]
    assert top_left[:, 0].mean() > bottom_right[:, 0].mean()


def test_render_many_matches_render(renderer, cube):
    rng = np.random.default_rng(0)
    T = touching([[0.02, 0.0, 0.0], [0.0, 0.02, 0.005], [0.0, 0.0, 0.02]], np.eye(3), rng.uniform(-3, 3, 3))
    images, masks = renderer.render_many(cube, T, seeds=[5, 6, 7])
    assert images.shape == (3, H, W, 3) and masks.shape == (3, H, W)
    for i in range(3):
        single = renderer.render(cube, IDENTITY, T[i], seed=5 + i)
        np.testing.assert_array_equal(images[i], single.image)
        np.testing.assert_array_equal(masks[i], single.mask)


@pytest.mark.slow  # starts two processes
def test_render_many_with_two_worker_processes(background, cube):
    T = touching(np.tile([0.02, 0.0, 0.0], (16, 1)), np.tile([1.0, 0, 0], (16, 1)), np.linspace(0, 3, 16))
    with DigitRenderer.from_default_config(background, workers=2) as parallel:
        images, masks = parallel.render_many(cube, T, seeds=100)
    serial = DigitRenderer.from_default_config(background)
    np.testing.assert_array_equal(images[9], serial.render(cube, IDENTITY, T[9], seed=109).image)
    assert masks.all(axis=(1, 2)).sum() == 0 and masks.any(axis=(1, 2)).all()


def test_object_inside_the_body_is_an_input_error(renderer, cube):
    # pressed 12 mm: the cube face is behind the gel, in the body
    with pytest.raises(InputError, match="inside the DIGIT body"):
        renderer.render(cube, IDENTITY, touching([0.02, 0, 0], [1, 0, 0], depth=0.012), seed=0)
    # pressed 6 mm, beyond the 5 mm gel
    with pytest.raises(InputError, match="presses"):
        renderer.render(cube, IDENTITY, touching([0.02, 0, 0], [1, 0, 0], depth=0.006), seed=0)
    with pytest.raises(InputError, match="sensor pose 1"):
        renderer.render_many(cube, touching([[0.02, 0, 0]] * 2, [[1, 0, 0]] * 2, depth=[0.001, 0.012]))


def test_lenient_renderer_renders_an_object_inside_the_body(background, cube):
    lenient = DigitRenderer.from_default_config(background, strict=False)
    result = lenient.render(cube, IDENTITY, touching([0.02, 0, 0], [1, 0, 0], depth=0.006), seed=0)
    assert result.mask.mean() > 0.9


def test_contact_depth_is_contact_without_the_shading(background, sphere, cube):
    rng = np.random.default_rng(4)
    for force in (0.0, 30.0):
        lenient = DigitRenderer.from_default_config(background, strict=False, force=force)
        for mesh in (sphere, cube):
            points, face = mesh.sample(6, return_index=True)
            poses = touching(points, mesh.face_normals[face], rng.uniform(-np.pi, np.pi, 6), rng.uniform(0.0, 0.004, 6))
            poses[0, :3, 3] -= 0.02 * poses[0, :3, 0]  # pulled away: no press at all
            depths = [lenient.contact_depth(mesh, g.invert_pose(T)) for T in poses]
            for T, depth in zip(poses, depths):
                np.testing.assert_array_equal(depth, lenient.contact(mesh, g.invert_pose(T))[1])
            assert not depths[0].any() and all(d.any() for d in depths[1:])
    with pytest.raises(InputError, match="inside the DIGIT body"):
        DigitRenderer.from_default_config(background).contact_depth(
            cube, g.invert_pose(touching([0.02, 0, 0], [1, 0, 0], depth=0.012)))


def test_ray_grid_gives_each_ray_and_its_gel_distance(background, sphere):
    """The grid's rays (x = 1) and each one's distance to the gel along the camera axis: a press's depth is
    that distance minus the hit's, so ``camera + (gel_t - depth) * ray`` lies on the object. The arrays
    returned are copies."""
    coarse = DigitRenderer.from_default_config(background, render_step=4, noise_std=0.0)
    rays, gel_t = coarse.ray_grid()
    h, w = coarse.grid_shape
    assert rays.shape == (h * w, 3) and gel_t.shape == (h * w,) and rays.dtype == gel_t.dtype == np.float32
    np.testing.assert_allclose(rays.reshape(h, w, 3), pixel_rays(W, H, 4), rtol=1e-6)
    points, _ = gel_surface(rays.astype(np.float64))
    np.testing.assert_allclose(gel_t, points[:, 0] - CAMERA_POSITION[0], rtol=1e-6)
    T = touching([0.015, 0.0, 0.0], [1.0, 0.0, 0.0], depth=0.0015)
    depth = coarse.contact_depth(sphere, g.invert_pose(T)).ravel()
    pressed = depth > 0
    assert pressed.sum() > 20
    on_object = CAMERA_POSITION + (gel_t[pressed] - depth[pressed])[:, None] * rays[pressed]
    in_object = on_object @ T[:3, :3].T + T[:3, 3]  # sensor frame -> the sphere's frame
    np.testing.assert_allclose(np.linalg.norm(in_object, axis=1), 0.015, atol=2e-4)  # icosphere facets
    rays[:] = 0.0
    gel_t[:] = 0.0
    again = coarse.ray_grid()
    assert np.all(again[0][:, 0] == 1.0) and np.all(again[1] > 0.0)


def test_degenerate_meshes_are_mesh_errors(renderer):
    empty = trimesh.Trimesh(vertices=np.zeros((3, 3)), faces=np.zeros((0, 3), dtype=int), process=False)
    flat = trimesh.Trimesh(vertices=np.zeros((3, 3)), faces=[[0, 1, 2]], process=False)
    for mesh in (empty, flat):
        with pytest.raises(MeshError):
            renderer.render(mesh, IDENTITY, IDENTITY, seed=0)
    with pytest.raises(MeshError):
        mesh_arrays("not a mesh")


def test_background_of_the_wrong_size_is_resized_with_a_warning(background):
    small = background[::2, ::2]
    with pytest.warns(UserWarning, match="resized"):
        resized = DigitRenderer.from_default_config(small)
    assert resized.no_contact(seed=0).shape == (H, W, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        DigitRenderer.from_default_config(background)


def test_every_setting_comes_from_the_render_config(background):
    cfg = compose_config().render
    assert DigitRenderer.from_config(cfg, background).settings == DigitRenderer.from_default_config(background).settings
    assert DigitRenderer.from_config(cfg, background).light_intensity == cfg.light_intensity
    partial = {k: v for k, v in cfg.items() if k != "light_intensity"}
    with pytest.raises(ConfigError, match=r"render config lacks keys \['light_intensity'\]"):
        DigitRenderer.from_config(partial, background)
    with pytest.raises(TypeError):
        DigitRenderer(background)  # no defaults in code: conf/render is their one home


def test_gel_surface_is_a_cap_that_sags_toward_the_image_corners():
    rays = pixel_rays(W, H)
    points, normals = gel_surface(rays)
    # The apex is on the optical axis at the gel centre. The gel's corners sag 5 mm, but the image's
    # corners see the gel well inside its corners (about 8 x 11 mm off-axis), where it sags about 3 mm.
    assert points[..., 0].max() == pytest.approx(sensor.GEL_CENTER[0], abs=1e-5)
    assert sensor.GEL_CENTER[0] - 0.0035 < points[..., 0].min() < sensor.GEL_CENTER[0] - 0.0025
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-12)
    assert np.all(normals[..., 0] < -0.9)  # facing the camera
