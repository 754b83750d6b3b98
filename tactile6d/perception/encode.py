"""Step 1, encode: tactile images -> latent angles and the sensors' contacts, with what it loads (the
autoencoder checkpoint, the database's latent angles, the sensor's no-contact image, the contact-patch
calibration).

The angle of an image is ``arccos(cos_sim(h, h_nc))``: how far its latent ``h`` is from the latent
``h_nc`` of the no-contact image, the one number tactile selection compares with the database's. The
contacts are the paper's landmarks, or each image's contact patch (``select.contacts``,
``tactile6d.perception.contacts``). With ``select.centre_images`` an image whose contact was read from its patch
is moved so that contact sits at the image centre before its angle is read: every database image was
rendered with the gel's apex on the surface, so its contact is at the centre, and the angle of the same
press seen 4 mm off-centre differs by more than ``select.delta_h`` (docs/contact_patch.md). Before any
of that, with ``select.align_light``, each image is brought to its no-contact image's light
(``align_light``, ``tactile6d.perception.photometric``).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from tactile6d.core.errors import DataError, InputError
from tactile6d.core.geometry import invert_pose, transform_points
from tactile6d.core.settings import SelectSettings
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_tactile_image
from tactile6d.data.object_artifacts import require
from tactile6d.data.third_party import DataStore
from tactile6d.perception import photometric
from tactile6d.perception.autoencoder import encode, latent_angles, load_checkpoint
from tactile6d.perception.contact_patch import PatchModel, centre_contact, image_to_patch, load_model
from tactile6d.perception.contacts import Contacts, patches_to_contacts, sensors_to_landmark_contacts
from tactile6d.perception.inputs import check_backgrounds


def load_background(cfg: Mapping, data_dir: str | Path | None = None) -> np.ndarray:
    """The no-contact image the tactile images were rendered over, (320, 240, 3) uint8 **RGB**.

    ``render.background`` is a path relative to the data directory: ``data_dir`` when given, else the
    one ``tactile6d.data.third_party.DataStore`` resolves from ``paths``. The PNG is read in RGB order like the
    tactile images (``hdf5.read_tactile_image``): the renderer takes the file in OpenCV's BGR order
    (``render.load_background_bgr``) and flips it to RGB itself, so its no-contact output is the file's
    RGB; the paper's images match it there channel for channel.
    """
    relpath = str(cfg["render"]["background"])
    if data_dir is not None:
        path = Path(data_dir) / relpath
        if not path.is_file():
            raise DataError(f"no-contact background {path} not found (render.background under the data directory)")
    else:
        path = DataStore(cfg["paths"]).path(relpath)
    return read_tactile_image(path)


# DIGIT units whose no-contact images are in the data directory, by name: an image passed without its own is read
# against the one it agrees with when it does not agree with the default (``KnownUnits``).
KNOWN_UNITS = {
    "Caddeo et al.'s DIGIT (digit/caddeo2023/background.png)": "digit/caddeo2023/background.png",
    "TACTO's example DIGIT (digit/tacto/bg_digit_240_320.jpg)": "digit/tacto/bg_digit_240_320.jpg",
}


class KnownUnits:
    """The no-contact images of the DIGIT units in ``KNOWN_UNITS``, (320, 240, 3) uint8 RGB by name, each read as
    ``load_background`` reads ``render.background`` (from ``data_dir``, else the data store of ``cfg``'s ``paths``),
    when first asked for: only an image that disagrees with its no-contact image needs them. ``own``: the user's
    units' no-contact images, name -> (320, 240, 3) uint8 RGB, known beside them (a lab's drawer of DIGITs,
    each recorded once); InputError for one that is not a no-contact image or whose name is already known."""

    def __init__(self, cfg: Mapping, data_dir: str | Path | None = None,
                 own: Mapping[str, np.ndarray] | None = None):
        self._paths = cfg["paths"]
        self._data_dir = data_dir
        self._own = check_unit_images(own or {})
        self._images: dict[str, np.ndarray] | None = None

    def images(self) -> dict[str, np.ndarray]:
        """Name -> no-contact image (320, 240, 3) uint8 RGB, the data directory's units first, read on the first
        call."""
        if self._images is None:
            self._images = {name: load_background({"render": {"background": path}, "paths": self._paths},
                                                  self._data_dir)
                            for name, path in KNOWN_UNITS.items()}
            self._images.update(self._own)
        return self._images


def check_unit_images(units: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Units' no-contact images, name -> (320, 240, 3) uint8 RGB, checked as a ``background`` is
    (``inputs.check_backgrounds``; the error names the unit) and against the names of ``KNOWN_UNITS`` -> a dict of
    them."""
    out = {}
    for name, image in units.items():
        if name in KNOWN_UNITS:
            raise InputError(f"unit name {name!r} is already a known unit's; give your unit another name")
        image = np.asarray(image)
        if image.ndim != 3:
            raise InputError(f"unit {name!r}: its no-contact image has shape {image.shape}, one (320, 240, 3) "
                             "image per unit")
        try:
            out[str(name)] = check_backgrounds(image)
        except InputError as exc:
            raise InputError(f"unit {name!r}: {exc}") from exc
    return out


def known_unit_images(units: KnownUnits | Mapping[str, np.ndarray]) -> Mapping[str, np.ndarray]:
    """Name -> no-contact image (320, 240, 3) uint8 RGB of ``KnownUnits`` (read now if not yet) or of a mapping
    given as it is."""
    return units.images() if isinstance(units, KnownUnits) else units


class LatentAngleEncoder:
    """Images (L, 320, 240, 3) uint8 RGB -> (L,) latent angles (rad) of a trained autoencoder.

    The angle is ``arccos(cos_sim(h, h_nc))`` with ``h_nc`` the no-contact latent the database angles
    were computed against (from latents.h5), so image and database angles are comparable. background:
    the no-contact image (320, 240, 3) uint8 RGB of the sensors whose images are encoded, or
    (L, 320, 240, 3) one per sensor, in sensor order; a call may pass its own (``backgrounds``).

    One ``h_nc`` serves every sensor, whatever its background: the model sees ``image - background``, so
    each sensor's own no-contact image is the same input (zero) and has the same latent; a per-sensor
    no-contact latent would be that one repeated, and the database's ``h_nc`` (of its noisy no-contact
    image) is the one its angles are measured from.
    """

    def __init__(self, model, norm, background: np.ndarray, latent_nc: np.ndarray):
        self.model, self.norm = model, norm
        self.background = np.asarray(background)
        self.latent_nc = np.asarray(latent_nc)

    @classmethod
    def from_checkpoint(cls, path: str | Path, background: np.ndarray, latent_nc: np.ndarray) -> LatentAngleEncoder:
        model, norm, _ = load_checkpoint(path)
        return cls(model, norm, background, latent_nc)

    def __call__(self, images: np.ndarray, backgrounds: np.ndarray | None = None) -> np.ndarray:
        return self.angles(self.latents(images, backgrounds))

    def latents(self, images: np.ndarray, backgrounds: np.ndarray | None = None) -> np.ndarray:
        """(L, 320, 240, 3) uint8 RGB -> (L, latent_dim) latents: the network's part of the encoding, each
        image against its sensor's no-contact image: ``backgrounds`` ((320, 240, 3) for all or
        (L, 320, 240, 3)) when given, else this encoder's ``background``."""
        return encode(self.model, self.norm, images, self.background if backgrounds is None else backgrounds)

    def angles(self, latents: np.ndarray) -> np.ndarray:
        """(L, latent_dim) latents -> (L,) angles (rad) against this encoder's no-contact latent."""
        return latent_angles(latents, self.latent_nc)

    def encodes_like(self, other: LatentAngleEncoder) -> bool:
        """Whether ``other`` gives the same latents for the same images (same network, normalisation and
        background), so that images can be encoded once for both; their no-contact latents may differ."""
        if self.model is not other.model:
            mine, theirs = self.model.state_dict(), other.model.state_dict()
            if mine.keys() != theirs.keys() or any(not mine[k].equal(theirs[k]) for k in mine):
                return False
        return self.norm == other.norm and np.array_equal(self.background, other.background)


def centre_images(images: np.ndarray, no_contact: np.ndarray, contacts: Contacts, T_world_sensors: np.ndarray) -> np.ndarray:
    """images (L, 320, 240, 3) uint8 RGB -> the same, each image whose contact was read from its patch
    (``contacts.from_patch``) moved so that contact appears at the image centre (``contact_patch.centre_contact``);
    the others unchanged. no_contact (320, 240, 3) uint8 RGB for all sensors, or (L, 320, 240, 3) one per
    sensor; T_world_sensors (L, 4, 4)."""
    out = np.array(images, copy=True)
    for i in np.flatnonzero(contacts.from_patch):
        point = transform_points(invert_pose(T_world_sensors[i]), contacts.points[i][None])[0]
        out[i] = centre_contact(images[i], sensor_background(no_contact, i), point)
    return out


def align_light(settings: SelectSettings, images: np.ndarray | None, no_contact: np.ndarray | None
                ) -> tuple[np.ndarray | None, list[photometric.LightFit] | None]:
    """The images (L, 320, 240, 3) uint8 RGB as every later reading sees them: with
    ``settings.aligns_light`` and no-contact images (as for ``centre_images``), each brought to its own
    sensor's no-contact image's light (``photometric.align_images``) -> (images, their ``LightFit``s);
    otherwise (images as given, None)."""
    if images is None or no_contact is None or not settings.aligns_light:
        return images, None
    per_sensor = no_contact if no_contact.ndim == 4 else np.broadcast_to(no_contact, np.shape(images))
    return photometric.align_images(images, per_sensor)


def align_light_to_known_units(settings: SelectSettings, images: np.ndarray, per_sensor: np.ndarray,
                               known_units: KnownUnits | Mapping[str, np.ndarray] | None):
    """``align_light`` of images (L, 320, 240, 3) against their no-contact images per_sensor (L, 320, 240, 3), each
    image whose no-contact image looks like another unit's read instead against the known unit's it agrees with
    (``photometric.known_units_agreeing``; none with ``known_units`` None). The known units are read only for such
    an image. -> (images aligned, their fits (None where the light is not aligned), the no-contact images per
    sensor read against, {image index: (known unit's name, its fit)} for those read against a known unit's)."""
    aligned, fits = align_light(settings, images, per_sensor)
    if fits is None or known_units is None or not any(fit.from_another_unit for fit in fits):
        return aligned, fits, per_sensor, {}
    library = known_unit_images(known_units)
    found = photometric.known_units_agreeing(images, fits, library)
    if not found:
        return aligned, fits, per_sensor, found
    per_sensor = per_sensor.copy()
    for i, (name, _) in found.items():
        per_sensor[i] = library[name]
    aligned, fits = align_light(settings, images, per_sensor)
    return aligned, fits, per_sensor, found


def sensor_background(no_contact: np.ndarray, i: int) -> np.ndarray:
    """Sensor i's no-contact image (320, 240, 3) of one for all (320, 240, 3) or one per sensor (L, 320, 240, 3)."""
    return no_contact[i] if no_contact.ndim == 4 else no_contact


def read_angles(encoder, settings: SelectSettings, images: np.ndarray, contacts: Contacts,
                T_world_sensors: np.ndarray, no_contact: np.ndarray | None,
                backgrounds: np.ndarray | None = None) -> np.ndarray:
    """The images' latent angles (L,) rad by ``encoder`` (images (L, 320, 240, 3) uint8 RGB -> (L,)),
    after ``centre_images`` when ``settings.centres_images``. contacts: as ``read_contacts`` returned;
    no_contact as for ``centre_images``. backgrounds: passed on to the encoder (``encoder(images,
    backgrounds)``) when given, for a call with its own no-contact images; None: the encoder's own."""
    images = images_to_encode(settings, images, contacts, T_world_sensors, no_contact)
    angles = encoder(images) if backgrounds is None else encoder(images, backgrounds)
    return np.asarray(angles, dtype=np.float64).reshape(len(images))


def images_to_encode(settings: SelectSettings, images: np.ndarray, contacts: Contacts,
                     T_world_sensors: np.ndarray, no_contact: np.ndarray | None) -> np.ndarray:
    """The images as the encoder sees them: ``centre_images`` when ``settings.centres_images``, else as given."""
    if settings.centres_images:
        return centre_images(images, no_contact, contacts, T_world_sensors)
    return images


def load_patch_model(artifacts_dir: str | Path) -> PatchModel:
    """The contact-patch calibration (stage calibrate_patch)."""
    return load_model(require(layout.patch_model_file(artifacts_dir), "calibrate_patch"))


def read_contacts(
    settings: SelectSettings,
    T_world_sensors: np.ndarray,
    images: np.ndarray | None = None,
    no_contact: np.ndarray | None = None,
    model: PatchModel | None = None,
) -> Contacts:
    """The sensors' contacts for one estimate: their landmarks, or (``settings.reads_patches``) each
    image's contact patch.

    T_world_sensors (L, 4, 4); images (L, 320, 240, 3) uint8 RGB, no_contact (320, 240, 3) uint8 RGB
    (the sensors' no-contact image) or (L, 320, 240, 3) (each sensor's own) and model (the patch
    calibration) are needed for patches.
    """
    if not settings.reads_patches:
        return sensors_to_landmark_contacts(T_world_sensors)
    if images is None or no_contact is None or model is None:
        raise InputError("select.contacts=patch needs the images, the no-contact image and the patch calibration")
    return patches_to_contacts([image_to_patch(im, sensor_background(no_contact, i), model)
                                for i, im in enumerate(images)], T_world_sensors)
