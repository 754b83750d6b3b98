"""Regenerate ``tactile6d/data/data_manifest.json`` from a local data directory (developer tool).

    python scripts/make_data_manifest.py /path/to/shared/data [-o tactile6d/data/data_manifest.json]

The manifest lists every third-party file the project reads, with its size, sha256 and the place it
came from upstream (GitHub repository, pinned commit, path in that repository), so that
``tactile6d.data.third_party`` can verify a local copy or download and verify the files on a fresh machine.
The list of files is fixed here, from the data layout described in ``shared/data/SOURCES.md``;
a needed file that is absent from the directory is an error, not a silent omission.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

# The two upstream snapshots every file comes from (SOURCES.md).
SOURCES = {
    "caddeo2023": {
        "repo": "hsp-iit/multi-tactile-6d-estimation",
        "commit": "e4e77b3cd8b4e163e349b4456961865c9a6ecd0d",
    },
    "tacto": {
        "repo": "facebookresearch/tacto",
        "commit": "a21d0c4626d74a546d94859226c2fea348babb6a",
    },
}

# local path -> path in the upstream repository, for the DIGIT assets.
DIGIT_FILES = {
    "digit/tacto/digit.STL": ("tacto", "meshes/digit.STL"),
    "digit/tacto/config_digit.yml": ("tacto", "tacto/config_digit.yml"),
    "digit/tacto/bg_digit_240_320.jpg": ("tacto", "examples/conf/bg_digit_240_320.jpg"),
    "digit/caddeo2023/background.png": ("caddeo2023", "background.png"),
}
OBJECTS_JSON = "caddeo2023/json/objects.json"
# Upstream held N copies of one multi-part file for these objects; the data directory keeps only
# textured_0.obj (see shared/data/ycb/README.md), so json/meshes.json's count does not apply to them.
SINGLE_COLLISION_FILE = {"011_banana", "021_bleach_cleanser", "040_large_marker"}
TRIPLETS_PER_OBJECT = 4
TRIPLET_FILES = ("Image_heatmap_0.png", "Image_heatmap_1.png", "Image_heatmap_2.png", "poses_sensors.txt", "sensors.off")
DATABASE_FILES = ("poses_images.txt", "poses_sensors.txt", "angles_database.txt")


def needed_files(data_dir: Path) -> dict[str, list[tuple[str, str, str]]]:
    """Group name -> [(local relpath, source key, upstream path)], for every file the project needs.

    The object list and the collision-piece counts are read from the data directory's own
    ``caddeo2023/json/{objects,meshes}.json``, so the manifest follows the paper's object set.
    """
    objects = json.loads((data_dir / OBJECTS_JSON).read_text())
    counts = [int(c) for c in json.loads((data_dir / "caddeo2023/json/meshes.json").read_text())]
    groups: dict[str, list[tuple[str, str, str]]] = {
        "meta": [(OBJECTS_JSON, "caddeo2023", "json/objects.json")],
        "digit": [(local, src, up) for local, (src, up) in DIGIT_FILES.items()],
    }
    for obj, count in zip(objects, counts, strict=True):
        n_collision = 1 if obj in SINGLE_COLLISION_FILE else count
        model = [(f"ycb/{obj}/{name}", "caddeo2023", f"models/{obj}/{name}") for name in ("textured_simple.obj", "points.xyz")]
        model += [
            (f"ycb/{obj}/collision_caddeo2023/textured_{i}.obj", "caddeo2023", f"models/{obj}/textured_{i}.obj")
            for i in range(n_collision)
        ]
        groups[f"object:{obj}"] = model
        groups[f"triplets:{obj}"] = [
            (f"caddeo2023/triplets/{obj}/triplet_{k}/{name}", "caddeo2023", f"final_triplets/{obj}/triplet_{k}/{name}")
            for k in range(1, TRIPLETS_PER_OBJECT + 1)
            for name in TRIPLET_FILES
        ]
        groups[f"database:{obj}"] = [
            (f"caddeo2023/point_clouds/{obj}/{name}", "caddeo2023", f"point_clouds/{obj}/{name}") for name in DATABASE_FILES
        ]
    return groups


def sha256_of(path: Path) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def build_manifest(data_dir: Path | str) -> dict:
    """The manifest for ``data_dir`` as a plain dict (what gets written as JSON)."""
    data_dir = Path(data_dir)
    groups = needed_files(data_dir)
    files: dict[str, dict] = {}
    missing = []
    for entries in groups.values():
        for local, src, upstream in entries:
            path = data_dir / local
            if not path.is_file():
                missing.append(local)
                continue
            files[local] = {"size": path.stat().st_size, "sha256": sha256_of(path), "source": src, "upstream_path": upstream}
    if missing:
        raise SystemExit(f"{data_dir} lacks {len(missing)} needed file(s), e.g. {missing[:3]}")
    return {
        "format": 1,
        "about": "Third-party files tactile6d reads; regenerate with scripts/make_data_manifest.py <data_dir>.",
        "sources": SOURCES,
        "groups": {name: [local for local, _, _ in entries] for name, entries in groups.items()},
        "files": dict(sorted(files.items())),
    }


def dumps(manifest: dict) -> str:
    """Stable JSON text, so regenerating an unchanged directory gives an unchanged file."""
    return json.dumps(manifest, indent=1) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_dir", type=Path, help="a data directory laid out like shared/data")
    parser.add_argument(
        "-o", "--output", type=Path, default=Path(__file__).resolve().parent.parent / "tactile6d" / "data_manifest.json"
    )
    args = parser.parse_args(argv)
    manifest = build_manifest(args.data_dir)
    args.output.write_text(dumps(manifest))
    total = sum(f["size"] for f in manifest["files"].values())
    print(f"wrote {args.output}: {len(manifest['files'])} files, {total} bytes, {len(manifest['groups'])} groups")
    return 0


if __name__ == "__main__":
    sys.exit(main())
