"""scripts/two_contact_confidence.py: the lifted sensor and the summary line, against numbers worked by hand."""

import numpy as np
from script_loader import load_script

from tactile6d.core.geometry import make_pose, rotvec_to_rotmat

two_contact = load_script("two_contact_confidence")


def test_lifting_moves_one_sensor_along_the_normal_and_blanks_its_image():
    T = np.stack([make_pose(rotvec_to_rotmat(np.array([0.1 * i, 0.2, -0.3])), np.array([i, 2.0, 3.0]))
                  for i in range(3)])
    images = np.arange(3 * 4 * 5 * 3, dtype=np.uint8).reshape(3, 4, 5, 3)
    blank = np.full((4, 5, 3), 7, dtype=np.uint8)
    lifted_T, lifted_images = two_contact.lift_sensor(T, images, 1, np.array([0.0, 3.0, 4.0]), 0.004, blank)
    np.testing.assert_allclose(lifted_T[1, :3, 3] - T[1, :3, 3], [0.0, 0.0024, 0.0032])
    np.testing.assert_array_equal(lifted_T[1, :3, :3], T[1, :3, :3])
    np.testing.assert_array_equal(lifted_T[[0, 2]], T[[0, 2]])
    np.testing.assert_array_equal(lifted_images[1], blank)
    np.testing.assert_array_equal(lifted_images[[0, 2]], images[[0, 2]])
    assert images[1].max() > 7 and T[1, 1, 3] == 2.0  # the inputs are left as they were


def test_the_summary_line_gives_share_confidence_auroc_and_brier():
    line = two_contact.summary_line("two contacts", np.array([0.9, 0.8, 0.3, 0.6]), np.array([True, True, False, False]))
    # AUROC: every right estimate above every wrong one; Brier: (0.01 + 0.04 + 0.09 + 0.36) / 4
    assert line == ("two contacts: 4 estimates, 0.500 within 1 cm ADI, mean confidence 0.650, AUROC 1.000, "
                    "Brier 0.125")
