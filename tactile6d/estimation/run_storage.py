"""The artifacts of the per-run stages (select_tuples -> optimize -> rank) and the
compact form in which pose hypotheses are stored.

Each artifact has one row per scene of the set. Ragged per-scene arrays are stacked over the scenes,
with ``offsets`` (S + 1,): scene s owns rows offsets[s]:offsets[s + 1]. ``failure`` (S,) says why a
scene has no estimate ('' when it has one); the sensor poses and the seconds of earlier steps are
carried forward so that each stage reads only its predecessor's file.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from tactile6d.core.geometry import make_pose, rotmat_to_rotvec, rotvec_to_rotmat
from tactile6d.perception.contacts import Contacts


def stack_ragged(parts: Sequence[np.ndarray], row_shape: tuple[int, ...], dtype) -> tuple[np.ndarray, np.ndarray]:
    """Per-scene arrays (n_s, *row_shape) -> (sum n_s, *row_shape) and offsets (S + 1,) int64."""
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in parts])]).astype(np.int64)
    rows = [np.asarray(p, dtype=dtype).reshape(-1, *row_shape) for p in parts]
    return (np.concatenate(rows) if rows else np.zeros((0, *row_shape), dtype)), offsets


def scene_rows(data: np.ndarray, offsets: np.ndarray, scene: int) -> np.ndarray:
    """Scene ``scene``'s rows of an array stacked by ``stack_ragged``."""
    return data[offsets[scene] : offsets[scene + 1]]

def stack_contacts(contacts: Sequence[Contacts], n_sensors: int) -> dict[str, np.ndarray]:
    """Each scene's contacts (L = n_sensors each) -> the CONTACT_FIELDS and PATCH_FIELDS arrays
    (tactile6d.data.schemas). The patches are kept only when every scene has them (source ``patch``)."""
    observed = bool(contacts) and all(c.observed for c in contacts)
    empty = np.zeros((len(contacts), n_sensors, 0, 0))
    return {
        "contact_points": np.array([c.points for c in contacts], dtype=np.float64).reshape(-1, n_sensors, 3),
        "contact_normals": np.array([c.normals for c in contacts], dtype=np.float64).reshape(-1, n_sensors, 3),
        "contact_from_patch": np.array([c.from_patch for c in contacts], dtype=bool).reshape(-1, n_sensors),
        "contact_masks": np.array([c.masks for c in contacts], dtype=bool) if observed else empty.astype(bool),
        "contact_depths": np.array([c.depths for c in contacts], dtype=np.float32) if observed
        else empty.astype(np.float32),
    }


def scene_contacts(art, scene: int) -> Contacts:
    """Scene ``scene``'s contacts from an artifact holding the CONTACT_FIELDS (and the PATCH_FIELDS, if it has them)."""
    masks = depths = None
    if "contact_masks" in art.data and art["contact_masks"].shape[-1] > 0:
        masks = np.asarray(art["contact_masks"][scene], dtype=bool)
        depths = np.asarray(art["contact_depths"][scene], dtype=np.float32)
    return Contacts(np.asarray(art["contact_points"][scene], dtype=np.float64),
                    np.asarray(art["contact_normals"][scene], dtype=np.float64),
                    np.asarray(art["contact_from_patch"][scene], dtype=bool), masks, depths)


def carried(art, keys: Sequence[str]) -> dict[str, np.ndarray]:
    """Datasets of a predecessor's artifact to write again; strings (read back as objects) -> str arrays."""
    return {k: np.asarray(art[k], dtype=str) if art[k].dtype == object else art[k] for k in keys}


def compact_hypotheses(poses: np.ndarray, losses: np.ndarray) -> dict[str, np.ndarray]:
    """Poses (P, 4, 4) and losses (P,) -> float32 ``translations`` (P, 3) m, ``rotvecs`` (P, 3) rad, ``losses``.

    The form hypotheses.h5 stores. The estimator ranks ``expand_hypotheses(compact_hypotheses(...))``
    too, so an offline run ranks exactly the poses an online estimate ranks: fcl's penetration depth
    is not continuous in the pose (EPA stops early on some contacts, see collision.py), so even the
    ~1e-8 m of float32 rounding could otherwise change a depth, and the ranking, now and then.
    """
    return {
        "translations": np.asarray(poses, dtype=np.float64)[:, :3, 3].astype(np.float32),
        "rotvecs": rotmat_to_rotvec(np.asarray(poses, dtype=np.float64)[:, :3, :3]).astype(np.float32),
        "losses": np.asarray(losses).astype(np.float32),
    }


def expand_hypotheses(translations, rotvecs, losses) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of ``compact_hypotheses``: -> poses (P, 4, 4) float64, losses (P,) float64."""
    R = rotvec_to_rotmat(np.asarray(rotvecs, dtype=np.float64))
    poses = make_pose(R, np.asarray(translations, dtype=np.float64))
    return poses, np.asarray(losses, dtype=np.float64)
