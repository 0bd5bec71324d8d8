"""sha256.json: the checksums of a saved directory and the run it belongs to.

Orbax checks neither the bytes it reads back nor whose state they are. Every save
(``checkpoint``) writes ``sha256.json`` inside the saved directory::

    {"algorithm": "sha256", "files": {relative name: sha256, ...},
     "run": {"config_sha256": ..., "seeds": [...]}}      # run_state.run_identity

and every load verifies it first: a changed byte names its file (``ChecksumError``), and a
directory of another run is refused (``ForeignRunError``).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from advisor_jax.fileio import atomic_write_json
from advisor_jax.training.run_state import describe_identity

CHECKSUMS = "sha256.json"


class ChecksumError(ValueError):
    """A saved directory's files differ from the checksums recorded when it was saved."""


class ForeignRunError(ValueError):
    """A saved directory belongs to another run than the one reading or writing it."""


def _file_sha256(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def record_checksums(directory: str | Path, run: dict | None = None) -> Path:
    """Writes ``directory/sha256.json``: the sha256 of every file below ``directory`` and,
    if given, the identity of the ``run`` it belongs to."""
    directory = Path(directory)
    files = {
        path.relative_to(directory).as_posix(): _file_sha256(path)
        for path in sorted(directory.rglob("*"))
        if path.is_file() and path.name != CHECKSUMS
    }
    manifest = {"algorithm": "sha256", "files": files}
    if run is not None:
        manifest["run"] = run
    return atomic_write_json(directory / CHECKSUMS, manifest)


def read_manifest(directory: str | Path) -> dict | None:
    """``directory/sha256.json`` checked for shape (None if there is none)."""
    manifest = Path(directory) / CHECKSUMS
    if not manifest.is_file():
        return None
    try:
        data = json.loads(manifest.read_text())
        files = data["files"]
        if not isinstance(files, dict) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in files.items()
        ):
            raise TypeError("files must map names to sha256 strings")
    except (ValueError, KeyError, TypeError, RecursionError) as e:
        raise ChecksumError(f"{manifest} is corrupt ({type(e).__name__}: {e})") from None
    for name in files:
        parts = Path(name).parts
        if Path(name).is_absolute() or ".." in parts or not parts:
            raise ChecksumError(f"{manifest} is corrupt: it names {name!r}, outside {directory}")
    return data


def check_run(directory: str | Path, run: dict, manifest: dict | None) -> None:
    """ForeignRunError unless ``manifest`` (of ``directory``) records ``run``."""
    if manifest is None:
        raise ChecksumError(
            f"{Path(directory) / CHECKSUMS} is missing: this run records checksums with every "
            "save, so the directory was damaged, cut short or put here by hand"
        )
    if manifest.get("run") != run:
        raise ForeignRunError(
            f"{directory} belongs to another run ({describe_identity(manifest.get('run'))}), "
            f"not this one ({describe_identity(run)}); it was copied or left here: remove it"
        )


def verify_checksums(directory: str | Path, run: dict | None = None) -> bool:
    """True if every file recorded in ``directory/sha256.json`` is present and unchanged;
    False if no checksums were recorded (an older save); ChecksumError naming the first
    bad file otherwise. Files added after the save are ignored (orbax never adds any).
    With ``run`` (an identity) the manifest is required and must record that run
    (``check_run``)."""
    directory = Path(directory)
    manifest = read_manifest(directory)
    if run is not None:
        check_run(directory, run, manifest)
    if manifest is None:
        return False
    for name, expected in sorted(manifest["files"].items()):
        path = directory / name
        if not path.is_file():
            raise ChecksumError(f"{path} is missing (recorded in {CHECKSUMS} at save time)")
        actual = _file_sha256(path)
        if actual != expected:
            raise ChecksumError(
                f"{path} has sha256 {actual[:12]}…, not the {str(expected)[:12]}… recorded "
                "when it was saved (the file was modified or damaged)"
            )
    return True


def manifest_sha256(path: str | Path) -> str:
    """sha256 of ``path/sha256.json``: run.json records it for ``params/``."""
    return _file_sha256(Path(path) / CHECKSUMS)
