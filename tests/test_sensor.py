import numpy as np

from tactile6d.core import geometry as g
from tactile6d.core import sensor


def test_touching_pose_faces_the_surface_and_presses_the_gel():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(50, 3))
    n = rng.normal(size=(50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    rolls = rng.uniform(-np.pi, np.pi, 50)
    T = sensor.sensor_poses_touching(p, n, rolls, depths=0.0015)
    assert np.all(g.is_rotation(T[:, :3, :3]))
    np.testing.assert_allclose(sensor.contact_normals(T), n, atol=1e-12)
    # the contact point sits 2 mm - depth outside the surface, on the normal through p
    np.testing.assert_allclose(sensor.contact_points(T), p + 0.0005 * n, atol=1e-12)
    apex = g.transform_points(T, sensor.GEL_CENTER[None, None, :])[:, 0]
    np.testing.assert_allclose(np.sum((apex - p) * n, axis=1), -0.0015, atol=1e-12)


def test_roll_turns_about_the_normal():
    p, n = np.zeros(3), np.array([0.0, 0.0, 1.0])
    T0 = sensor.sensor_poses_touching(p, n, 0.0)
    T1 = sensor.sensor_poses_touching(p, n, np.pi / 2)
    np.testing.assert_allclose(T1[:3, 1], T0[:3, 2], atol=1e-12)


def test_surface_points_invert_the_placement():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(50, 3))
    normals = rng.normal(size=(50, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    depths = rng.uniform(0.0005, 0.0025, 50)
    T = sensor.sensor_poses_touching(points, normals, rng.uniform(-np.pi, np.pi, 50), depths)
    np.testing.assert_allclose(sensor.sensor_poses_to_surface_points(T, depths), points, rtol=0, atol=1e-12)
    # any batch shape, and one depth for all
    T = sensor.sensor_poses_touching(points.reshape(5, 10, 3), normals.reshape(5, 10, 3), 0.3, 0.002)
    np.testing.assert_allclose(sensor.sensor_poses_to_surface_points(T, 0.002), points.reshape(5, 10, 3),
                               rtol=0, atol=1e-12)
