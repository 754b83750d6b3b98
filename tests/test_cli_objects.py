"""tactile6d.cli.objects: which names the commands know, where their artifacts live, and the one error that
names every missing artifact with the dvc targets that make it."""

import pytest

from tactile6d.cli.objects import KnownObjects
from tactile6d.core.config import compose_config
from tactile6d.core.errors import ArtifactError, InputError
from tactile6d.data import layout


def _touch(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")
    return path


@pytest.fixture
def artifacts(tmp_path):
    """004_sugar_box prepared but not sampled; prim_box with every file; shape_3 a distractor with its object file."""
    _touch(layout.object_file(tmp_path, "004_sugar_box"))
    for path_of in (layout.object_file, layout.surface_file, layout.latents_file):
        _touch(path_of(tmp_path, "prim_box"))
    _touch(layout.object_file(layout.distractors_dir(tmp_path), "shape_3"))
    return tmp_path


def test_objects_and_distractors_live_where_their_artifacts_are(artifacts):
    known = KnownObjects(artifacts, compose_config())
    assert known.get("prim_box").objects_dir == artifacts and not known.get("prim_box").distractor
    shape = known.get("shape_3")
    assert shape.distractor and shape.objects_dir == layout.distractors_dir(artifacts)
    # a configured distractor without any artifact yet is one too; a configured object is not
    assert known.get("prim_sphere").distractor and not known.get("011_banana").distractor
    with pytest.raises(InputError, match=r"unknown object 'mug'; .*distractors of the identification library: "):
        known.get("mug")


def test_one_error_names_every_missing_file_and_every_target(artifacts):
    known = KnownObjects(artifacts, compose_config())
    with pytest.raises(ArtifactError) as info:
        known.require_artifacts("011_banana")
    message = str(info.value)
    for kind in ("objects", "surfaces", "latents"):
        assert f"{kind}/011_banana.h5" in message
    targets = "prepare_object@011_banana sample_surface@011_banana encode_database@011_banana"
    assert message.endswith(f"make them with `dvc repro {targets}`")
    with pytest.raises(ArtifactError, match=r"surfaces/004_sugar_box.h5: missing; make it with "
                                            r"`dvc repro sample_surface@004_sugar_box`$"):
        known.require_artifacts("004_sugar_box", baseline=True)  # the baseline reads no latents
    with pytest.raises(ArtifactError, match=r"make them with `dvc repro sample_distractors encode_distractors`$"):
        known.require_artifacts("shape_3")
    assert known.require_artifacts("prim_box").objects_dir == artifacts


def test_an_object_no_stage_makes_says_what_to_configure(artifacts):
    known = KnownObjects(artifacts, compose_config(["identify.distractors=[]"]))
    assert not known.get("prim_sphere").distractor  # still known: conf/objects/primitives.yaml lists it
    with pytest.raises(ArtifactError, match=r"no stage makes them: 'prim_sphere' is in none of the pipeline's "
                                            r"object lists; add it to objects.names"):
        known.require_artifacts("prim_sphere")
