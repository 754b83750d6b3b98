"""scripts/cpu_digests.py: the lines two machines compare."""


import pytest

from script_loader import load_script

cpu_digests = load_script("cpu_digests")


def test_the_cpu_is_named():
    identity = cpu_digests.cpu_identity()
    assert set(identity) == {"cpu", "vendor", "family", "model", "avx512f"}
    assert identity["vendor"] in ("GenuineIntel", "AuthenticAMD") and identity["family"].isdigit()


@pytest.mark.slow
def test_turning_onednn_off_changes_the_autoencoders_alone():
    """The variant does what it says: the convolutions take another path (other bits), nothing else moves."""
    pinned, off = (cpu_digests.run_child(prelude) for prelude in cpu_digests.VARIANTS.values())
    torch_made = {"autoencoder", "pipeline_autoencoder"}
    assert all(pinned[k] != off[k] for k in torch_made)
    assert {k: v for k, v in pinned.items() if k not in torch_made} == {k: v for k, v in off.items() if k not in torch_made}
