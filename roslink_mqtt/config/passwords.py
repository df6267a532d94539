"""Mosquitto-compatible password hashes.

We store credentials exactly as ``mosquitto_passwd`` writes them so a single
robots.yaml serves the embedded broker and an exported Mosquitto password
file alike:

* ``$7$<iterations>$<salt b64>$<hash b64>`` — PBKDF2-HMAC-SHA512 (what we write)
* ``$6$<salt b64>$<hash b64>`` — SHA512(password + salt), Mosquitto ≤ 1.6 (verified only)
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import os

# OWASP's guidance for PBKDF2-HMAC-SHA512 (2023): ~0.1 s of one core per verification here, which the broker pays
# once per login (VerifiedLogins), not per connection. Mosquitto reads the count from each hash: any count works.
DEFAULT_ITERATIONS = 210_000
SALT_BYTES = 12  # what mosquitto_passwd uses
MAX_ITERATIONS = 10_000_000


class PasswordHashError(ValueError):
    """A stored hash is not in a format we (and Mosquitto) understand."""


def hash_password(password: str, *, iterations: int = DEFAULT_ITERATIONS, salt: bytes | None = None) -> str:
    """Hash ``password`` the way ``mosquitto_passwd`` does (PBKDF2-SHA512)."""
    if not password:
        raise ValueError("password must not be empty")
    if not 1 <= iterations <= MAX_ITERATIONS:
        raise ValueError(f"iterations must be 1..{MAX_ITERATIONS}")
    salt = os.urandom(SALT_BYTES) if salt is None else salt
    digest = hashlib.pbkdf2_hmac("sha512", password.encode(), salt, iterations)
    return f"$7${iterations}${_b64(salt)}${_b64(digest)}"


def check_hash_format(stored: str) -> None:
    """Raise PasswordHashError unless ``stored`` is a hash we can verify."""
    parse_hash(stored)


def verify_password(password: str, stored: str) -> bool:
    """True when ``password`` matches ``stored``; constant-time comparison."""
    algorithm, iterations, salt, expected = parse_hash(stored)
    if algorithm == "7":
        actual = hashlib.pbkdf2_hmac("sha512", password.encode(), salt, iterations)
    else:
        actual = hashlib.sha512(password.encode() + salt).digest()
    return hmac.compare_digest(actual, expected)


class VerifiedLogins:
    """Passwords that matched their stored hash, remembered so that a login is verified slowly once, not on every
    connection: a fleet reconnecting after a network hiccup (hundreds of robots, each a PBKDF2 at
    DEFAULT_ITERATIONS) costs a keyed SHA-256 each.

    What is kept is an HMAC of the password under a random per-process key, by stored hash: nothing here helps an
    attacker who reads the process's memory less than the hashes themselves would, a new password (a reload with a
    new hash) is verified slowly again, and only verified logins are kept (at most one entry per login: a flood of
    wrong passwords adds nothing). A wrong password is always a full PBKDF2.
    """

    def __init__(self, max_entries: int = 100_000) -> None:
        self._key = os.urandom(32)
        self._verified: dict[str, bytes] = {}  # stored hash → HMAC(key, password)
        self.max_entries = max_entries
        self.slow = self.fast = 0  # verifications by PBKDF2, and by the remembered HMAC

    def _tag(self, password: str, stored: str) -> bytes:
        return hmac.new(self._key, stored.encode() + b"\0" + password.encode(), hashlib.sha256).digest()

    def remembered(self, password: str, stored: str) -> bool:
        """The fast path alone: ``password`` matched ``stored`` before (a keyed SHA-256, no PBKDF2). The broker asks
        this on its event loop, so a verified login never waits behind other logins' slow checks."""
        known = self._verified.get(stored)
        if known is not None and hmac.compare_digest(known, self._tag(password, stored)):
            self.fast += 1
            return True
        return False

    def verify(self, password: str, stored: str) -> bool:
        """As :func:`verify_password`, fast for a password that matched ``stored`` before."""
        if self.remembered(password, stored):
            return True
        tag = self._tag(password, stored)
        self.slow += 1
        if not verify_password(password, stored):
            return False
        if stored in self._verified or len(self._verified) < self.max_entries:
            self._verified[stored] = tag
        return True


def parse_hash(stored: str) -> tuple[str, int, bytes, bytes]:
    """A stored hash's parts: (scheme "7" or "6", iterations, salt, digest); PasswordHashError when malformed."""
    if not isinstance(stored, str):
        raise PasswordHashError("password hash must be a string")
    parts = stored.split("$")
    try:
        if len(parts) == 5 and parts[0] == "" and parts[1] == "7":
            iterations = int(parts[2])
            if not 1 <= iterations <= MAX_ITERATIONS:
                raise PasswordHashError(f"iteration count {iterations} out of range")
            return "7", iterations, _unb64(parts[3]), _unb64(parts[4])
        if len(parts) == 4 and parts[0] == "" and parts[1] == "6":
            return "6", 1, _unb64(parts[2]), _unb64(parts[3])
    except (ValueError, binascii.Error) as err:
        if isinstance(err, PasswordHashError):
            raise
        raise PasswordHashError(f"malformed password hash ({err})") from None
    raise PasswordHashError(
        "not a Mosquitto password hash (expected $7$<iterations>$<salt>$<hash>; "
        "make one with `roslink-mqtt passwd`)")


def _b64(raw: bytes) -> str:
    return base64.b64encode(raw).decode("ascii")


def _unb64(text: str) -> bytes:
    return base64.b64decode(text.encode("ascii"), validate=True)
