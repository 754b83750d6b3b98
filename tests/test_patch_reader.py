"""tactile6d.perception.patch_reader: contact patches read in worker processes are those read in this process.

The images are presses rendered on superquadrics (as tests/test_contact_patch.py renders them) and a frame without
contact, read under their no-contact image's light and under a drifted light brought back by its fit.
"""

import dataclasses

import numpy as np
import pytest
from test_contact_patch import BOX, SPHERE, press, smooth_background
from test_estimator import small_patch_model

from tactile6d.core.errors import ConfigError, InputError
from tactile6d.perception import contact_patch, photometric
from tactile6d.perception.patch_reader import PatchReader, read_patch
from tactile6d.sim import perturb
from tactile6d.sim.render import DigitRenderer


@pytest.fixture(scope="module")
def frame():
    """(images (3, 320, 240, 3): a sphere, a box's face and nothing pressed; their no-contact image; the model)."""
    renderer = DigitRenderer.from_default_config(smooth_background())
    meshes = {}
    mesh_of = (lambda s: meshes.setdefault(s, contact_patch.shape_to_mesh(s)))
    sphere = press(renderer, mesh_of, SPHERE, [-0.01, 0.0, 0.0], [-1.0, 0.0, 0.0], tilt=0.2, seed=1)[0].image
    face = press(renderer, mesh_of, BOX, [-0.03, 0.004, -0.003], [-1.0, 0.0, 0.0], depth=0.001, seed=2)[0].image
    return np.stack([sphere, face, renderer.no_contact(seed=3)]), renderer.no_contact(seed=4), small_patch_model()


def assert_same_patch(a: contact_patch.ContactPatch, b: contact_patch.ContactPatch) -> None:
    for name in (f.name for f in dataclasses.fields(contact_patch.ContactPatch)):
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            np.testing.assert_array_equal(x, y, err_msg=name)
            assert np.asarray(x).dtype == np.asarray(y).dtype, name
        else:
            assert x == y or (x != x and y != y), name  # NaN == NaN here


@pytest.mark.slow
def test_patches_read_in_workers_are_those_read_here_bit_for_bit(frame):
    images, no_contact, model = frame
    with PatchReader(2) as reader:
        patches = reader.results(reader.submit(images, [no_contact] * 3, [None] * 3, model))
    assert [p.contact for p in patches] == [True, True, False]
    for image, patch in zip(images, patches):
        assert_same_patch(patch, contact_patch.image_to_patch(image, no_contact, model))


@pytest.mark.slow
def test_an_applied_light_fit_is_applied_before_reading_and_one_not_applied_is_not(frame):
    """read_patch brings an image to its no-contact image's light by its fit where the fit was applied, as the
    tracker does in this process (photometric.apply_fit), and reads it as given otherwise."""
    images, no_contact, model = frame
    drifted = perturb.drift_image_light(images[0], [1.08, 0.93, 1.04], [0.9, 1.1, 1.0])
    aligned, fits = photometric.align_images(drifted[None], no_contact[None])
    assert fits[0].applied
    unapplied = dataclasses.replace(fits[0], applied=False)
    with PatchReader(1) as reader:
        read, as_given = reader.results(reader.submit(np.stack([drifted, drifted]), [no_contact] * 2,
                                                      [fits[0], unapplied], model))
    assert_same_patch(read, contact_patch.image_to_patch(aligned[0], no_contact, model))
    assert_same_patch(read, read_patch(drifted, no_contact, fits[0], model))
    assert_same_patch(as_given, contact_patch.image_to_patch(drifted, no_contact, model))
    assert not np.array_equal(read.depth, as_given.depth)


@pytest.mark.slow
def test_a_workers_error_is_raised_to_the_caller(frame):
    images, no_contact, model = frame
    with PatchReader(1) as reader:
        futures = reader.submit(images[:1], [no_contact[:100]], [None], model)  # a cropped no-contact image
        with pytest.raises(InputError):
            reader.results(futures)


@pytest.mark.parametrize("processes", [0, -1, 1.5, True])
def test_a_reader_needs_a_whole_number_of_processes(processes):
    with pytest.raises(ConfigError, match="processes"):
        PatchReader(processes)


def test_one_no_contact_image_and_one_fit_per_image(frame):
    images, no_contact, model = frame
    with PatchReader(1) as reader, pytest.raises(ValueError, match="3 images, 2 no-contact images"):
        reader.submit(images, [no_contact] * 2, [None] * 3, model)


@pytest.mark.slow
def test_a_script_without_a_main_guard_is_an_error_not_a_hang(tmp_path):
    """Each spawn worker imports the caller's script again; one whose top level starts the reader kills the
    workers as they start. That is a RuntimeError naming the guard, raised before any image is queued."""
    import subprocess
    import sys
    import textwrap

    script = tmp_path / "no_guard.py"
    script.write_text(textwrap.dedent("""
        import numpy as np
        from tactile6d.perception.patch_reader import PatchReader

        image = np.zeros((320, 240, 3), np.uint8)
        reader = PatchReader(2)
        futures = [reader.submit(np.stack([image] * 3), [image] * 3, [None] * 3, None) for _ in range(8)]
        PatchReader.results(futures[0])
    """))
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode != 0
    assert "RuntimeError: the contact patches' worker processes died while starting" in done.stderr
    assert 'if __name__ == "__main__":' in done.stderr
