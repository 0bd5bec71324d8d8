"""Signed exports: an HMAC-SHA256 of policy.json under a key the exporter and the car share.

The hashes in policy.json detect damage, not a forger, who can recompute them. A key that
only the exporter and the car hold closes that gap (standard library ``hmac``: the runner
stays numpy-only)::

    advisor-jax export RUN --out policy/ --sign-key car.key     # writes policy/policy.sig
    advisor-jax-car policy/ --verify-key car.key ...            # refuses a bad signature

policy.json records the sha256 of every other file of the export (weights, golden set,
ONNX model) and of its own contents, so the MAC of its exact bytes covers the whole export:
one changed byte anywhere is refused. ``policy.sig`` is a JSON object::

    {"algorithm": "hmac-sha256", "file": "policy.json",
     "key_id": first 16 hex digits of sha256(key), "hmac": hex digest}

A key file holds at least ``MIN_KEY_BYTES`` bytes (e.g. ``head -c 32 /dev/urandom >
car.key``); surrounding ASCII whitespace is ignored, so a hex key written with a newline
works too. The key never enters the export; ``key_id`` only tells which key signed it.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os

from advisor_jax.runner.errors import PolicyError

SIGNATURE_FILE = "policy.sig"
ALGORITHM = "hmac-sha256"
MIN_KEY_BYTES = 16


def read_key(path: str | os.PathLike, option: str = "--verify-key") -> bytes:
    """The key in ``path``; ValueError naming the option if unreadable or too short."""
    try:
        with open(path, "rb") as f:
            key = f.read().strip()
    except OSError as e:
        why = e.strerror or e
        raise ValueError(f"{option} {os.fspath(path)}: cannot read it ({why})") from None
    if len(key) < MIN_KEY_BYTES:
        raise ValueError(
            f"{option} {os.fspath(path)}: a key needs at least {MIN_KEY_BYTES} bytes, this one "
            f"has {len(key)} (make one with: head -c 32 /dev/urandom > KEYFILE)"
        )
    return key


def key_id(key: bytes) -> str:
    return hashlib.sha256(key).hexdigest()[:16]


def _mac(policy_json: bytes, key: bytes) -> str:
    return hmac.new(key, policy_json, hashlib.sha256).hexdigest()


def sign(policy_json: bytes, key: bytes) -> bytes:
    """The contents of policy.sig for the exact bytes of policy.json."""
    record = {
        "algorithm": ALGORITHM,
        "file": "policy.json",
        "key_id": key_id(key),
        "hmac": _mac(policy_json, key),
    }
    return (json.dumps(record, indent=1) + "\n").encode("ascii")


def verify(sig_path: str, sig_bytes: bytes | None, policy_json: bytes, key: bytes) -> None:
    """PolicyError unless ``sig_bytes`` (policy.sig, None if missing) is a valid signature
    of ``policy_json`` under ``key``."""
    if sig_bytes is None:
        raise PolicyError(
            f"{sig_path}: missing: the export is not signed, and this car verifies signatures "
            "(export it with --sign-key)"
        )
    try:
        record = json.loads(sig_bytes.decode("ascii"))
        algorithm, mac, signer = record["algorithm"], record["hmac"], record["key_id"]
    except (UnicodeDecodeError, ValueError, KeyError, TypeError, RecursionError) as e:
        raise PolicyError(f"{sig_path}: not a signature file ({type(e).__name__})") from None
    if algorithm != ALGORITHM or not isinstance(mac, str):
        raise PolicyError(f"{sig_path}: algorithm {algorithm!r} is not {ALGORITHM}")
    if signer != key_id(key):
        raise PolicyError(
            f"{sig_path}: signed with key {str(signer)[:16]}, not with this car's key {key_id(key)}"
        )
    if not hmac.compare_digest(mac, _mac(policy_json, key)):
        raise PolicyError(
            f"{sig_path}: the signature does not match policy.json: the export was changed "
            "after it was signed"
        )
