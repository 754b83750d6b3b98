"""scripts/cpu_digests.py: the lines two machines compare."""


import pytest

from script_loader import load_script

cpu_digests = load_script("cpu_digests")


def test_the_cpu_is_named():
    identity = cpu_digests.cpu_identity()
    assert set(identity) == {"cpu", "vendor", "family", "model", "avx512f", "threads_per_core", "caches"}
    assert identity["vendor"] in ("GenuineIntel", "AuthenticAMD") and identity["family"].isdigit()


def test_the_topology_counts_the_processors_that_share_each_data_cache(tmp_path):
    cpu0 = tmp_path / "cpu0"
    (cpu0 / "topology").mkdir(parents=True)
    (cpu0 / "topology" / "thread_siblings_list").write_text("0,8\n")  # two hardware threads per core
    for i, (level, kind, size, shared) in enumerate([(1, "Data", "48K", "0,8"), (1, "Instruction", "32K", "0,8"),
                                                      (2, "Unified", "2048K", "0,8"), (3, "Unified", "107520K", "0-15,32-47")]):
        d = cpu0 / "cache" / f"index{i}"
        d.mkdir(parents=True)
        for name, value in (("level", level), ("type", kind), ("size", size), ("shared_cpu_list", shared)):
            (d / name).write_text(f"{value}\n")
    assert cpu_digests.cpu_topology(cpu0) == {"threads_per_core": "2", "caches": "L1 48K/2 L2 2048K/2 L3 107520K/32"}
    assert cpu_digests.cpu_topology(tmp_path / "absent") == {"threads_per_core": "", "caches": ""}


@pytest.mark.slow
def test_turning_onednn_off_changes_the_autoencoders_alone():
    """The variant does what it says: the convolutions take another path (other bits), nothing else moves."""
    pinned, off = (cpu_digests.run_child(prelude) for prelude in cpu_digests.VARIANTS.values())
    torch_made = {"autoencoder", "pipeline_autoencoder"}
    assert all(pinned[k] != off[k] for k in torch_made)
    assert {k: v for k, v in pinned.items() if k not in torch_made} == {k: v for k, v in off.items() if k not in torch_made}
