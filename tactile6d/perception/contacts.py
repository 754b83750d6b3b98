"""Where each sensor touches the object: one contact point and outward surface normal per sensor, in the
world frame, and what its image shows of the contact.

Two sources (config ``select.contacts``):

- ``landmark``, the paper's assumption: the object touches every sensor at the gel landmark
  ``sensor.CONTACT_POINT``, with its surface normal along the sensor's -x axis. The landmark sits a
  fraction of a millimetre outside the object's surface (how far depends on the press depth).
- ``patch``: each image's contact patch (``tactile6d.patch.image_to_patch``): the object's surface point
  where it presses deepest and its normal there, wherever on the gel that is and however the sensor is
  tilted. The points lie on the surface. A sensor whose image shows no contact keeps its landmark
  (``from_patch`` says which), so that every sensor still has a point; but when another sensor's image
  does show contact, the object is taken not to touch it (``Contacts.touching``): selection and the fit
  then use the touching sensors alone, and the ranking checks that no pose presses the others.

The patch source also keeps each sensor's observed contact mask and press depth on the image, which
render-and-compare ranking checks hypotheses against (``tactile6d.estimation.render_and_compare``).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tactile6d.core import sensor
from tactile6d.core.errors import InputError
from tactile6d.perception.contact_patch import ContactPatch, pixels_to_points


@dataclass(frozen=True)
class Contacts:
    """The sensors' contacts for one estimate (L sensors).

    points (L, 3) m and normals (L, 3) unit, world frame; from_patch (L,) bool: the sensor's point was
    read from its image and lies on the object's surface, rather than being its landmark, just outside
    the surface (all False for the landmark source; False for a patch source's sensor whose image shows
    no contact); masks (L, 320, 240) bool and depths (L, 320, 240) float32 m: the
    observed contact patches (None for landmarks).
    """

    points: np.ndarray
    normals: np.ndarray
    from_patch: np.ndarray
    masks: np.ndarray | None = None
    depths: np.ndarray | None = None

    @property
    def observed(self) -> bool:
        """Whether the observed patches are known (render-and-compare can use them)."""
        return self.masks is not None

    @property
    def touching(self) -> np.ndarray:
        """(L,) bool: the sensors the object touches, as far as the images tell.

        Read from images, a sensor whose image shows no contact does not touch (a finger lifted off, or one
        that missed the object), provided another sensor's image shows contact. Landmarks, or images none of
        which shows contact, tell nothing: every sensor then counts as touching (the paper's assumption).
        """
        if not self.observed or not self.from_patch.any():
            return np.ones(len(self.points), dtype=bool)
        return self.from_patch.copy()

    def of_sensors(self, on: np.ndarray) -> Contacts:
        """The contacts of the sensors ``on`` (K,) int only, in that order."""
        pick = (lambda a: None if a is None else a[on])
        return Contacts(self.points[on], self.normals[on], self.from_patch[on], pick(self.masks), pick(self.depths))

    def offsets(self, landmark_offset: float) -> np.ndarray:
        """(L,) m: how far outside the object's surface each point should sit: 0 for a point read from its
        image, ``landmark_offset`` for a landmark (its distance depends on the press, a config value)."""
        return np.where(self.from_patch, 0.0, float(landmark_offset))

    def patch_points(self, T_world_sensors: np.ndarray, max_per_sensor: int) -> tuple[np.ndarray, np.ndarray]:
        """Points of the observed patches' pressed gel, which lie on the object's surface, world frame.

        T_world_sensors (L, 4, 4). Each sensor read from its image gives up to ``max_per_sensor`` of its
        mask's pixels, evenly spread over the mask, lifted to the gel surface at their press depth
        (``contact_patch.pixels_to_points``). -> points (M, 3) m and the sensor of each (M,) int.
        """
        if not self.observed or max_per_sensor < 1:
            return np.zeros((0, 3)), np.zeros(0, dtype=int)
        T = np.asarray(T_world_sensors, dtype=np.float64)
        points, owners = [], []
        for i in np.flatnonzero(self.from_patch):
            rows, cols = np.nonzero(self.masks[i])
            if len(rows) == 0:
                continue
            pick = np.unique(np.linspace(0, len(rows) - 1, min(max_per_sensor, len(rows))).round().astype(int))
            local = pixels_to_points(self.depths[i], rows[pick], cols[pick])
            points.append(local @ T[i, :3, :3].T + T[i, :3, 3])
            owners.append(np.full(len(pick), i))
        if not points:
            return np.zeros((0, 3)), np.zeros(0, dtype=int)
        return np.concatenate(points), np.concatenate(owners)

    def free_points(self, T_world_sensors: np.ndarray, stride: int) -> tuple[np.ndarray, np.ndarray]:
        """Points of the gel the observed patches leave untouched, where the object's surface must not be.

        T_world_sensors (L, 4, 4). Each sensor read from its image gives the pixels outside its mask on a
        grid of ``stride`` pixels, lifted to the undeformed gel surface (press depth 0). -> points (F, 3) m,
        world frame, and the sensor of each (F,) int (none for a sensor without contact, nor without
        observed patches).
        """
        if not self.observed or stride < 1:
            return np.zeros((0, 3)), np.zeros(0, dtype=int)
        T = np.asarray(T_world_sensors, dtype=np.float64)
        points, owners = [], []
        for i in np.flatnonzero(self.from_patch):
            grid = np.zeros(self.masks[i].shape, dtype=bool)
            grid[stride // 2 :: stride, stride // 2 :: stride] = True
            rows, cols = np.nonzero(grid & ~self.masks[i])
            if len(rows) == 0:
                continue
            local = pixels_to_points(np.zeros(self.masks[i].shape, dtype=np.float32), rows, cols)
            points.append(local @ T[i, :3, :3].T + T[i, :3, 3])
            owners.append(np.full(len(rows), i))
        if not points:
            return np.zeros((0, 3)), np.zeros(0, dtype=int)
        return np.concatenate(points), np.concatenate(owners)


class UntouchedSensorWarning(UserWarning):
    """Some sensors' images show no contact while others' do: the estimate rests on those that do. Or none
    shows contact: the estimate rests on the sensor poses alone."""


def warn_if_untouched(contacts: Contacts, stacklevel: int = 4) -> None:
    """An ``UntouchedSensorWarning`` naming the sensors the object does not touch (``Contacts.touching``),
    when there are any, or saying that no image shows contact. stacklevel: as ``warnings.warn``'s."""
    if contacts.observed and not contacts.from_patch.any():
        # Every sensor then counts as touching (``touching``), so a selection that finds nothing would
        # otherwise blame the database or the object.
        warnings.warn("no contact in any sensor's image: the pose rests on the sensor poses alone, each sensor taken "
                      "to touch at its gel's centre; check that the images were taken while the object touched the "
                      "sensors and that each no-contact image is its own sensor's", UntouchedSensorWarning,
                      stacklevel=stacklevel)
        return
    touching = contacts.touching
    if touching.all():
        return
    off, on = np.flatnonzero(~touching), np.flatnonzero(touching)
    warnings.warn(f"no contact in the image of sensor(s) {', '.join(map(str, off))}: the pose rests on sensor(s) "
                  f"{', '.join(map(str, on))} (a pose that presses the others is penalised)"
                  + ("; with one contact it is under-determined (the rotation about its normal and a slide along "
                     "the surface are not observed)" if len(on) == 1 else ""),
                  UntouchedSensorWarning, stacklevel=stacklevel)


def sensors_to_landmark_contacts(T_world_sensors: np.ndarray) -> Contacts:
    """The paper's contacts: (L, 4, 4) sensor poses -> each sensor's landmark and -x axis."""
    T = np.asarray(T_world_sensors, dtype=np.float64)
    return Contacts(sensor.contact_points(T), sensor.contact_normals(T), np.zeros(T.shape[0], dtype=bool))


def patches_to_contacts(patches: Sequence[ContactPatch], T_world_sensors: np.ndarray) -> Contacts:
    """Contacts read from the sensors' images: L patches (sensor frames) and (L, 4, 4) sensor poses.

    A patch without contact keeps the sensor's landmark and -x axis (``from_patch`` is False there).
    """
    T = np.asarray(T_world_sensors, dtype=np.float64)
    if len(patches) != T.shape[0]:
        raise InputError(f"{len(patches)} contact patches for {T.shape[0]} sensors")
    fallback = sensors_to_landmark_contacts(T)
    points, normals = fallback.points.copy(), fallback.normals.copy()
    from_patch = np.array([p.contact for p in patches], dtype=bool)
    for i, p in enumerate(patches):
        if p.contact:
            R, t = T[i, :3, :3], T[i, :3, 3]
            points[i] = R @ p.point + t
            normals[i] = R @ p.normal
    masks = np.stack([p.mask for p in patches]).astype(bool)
    depths = np.stack([p.depth for p in patches]).astype(np.float32)
    return Contacts(points, normals, from_patch, masks, depths)
