"""Password hashes at today's iteration count, and the broker's memory of verified logins
(roslink_mqtt/config/passwords.py): slow once per login, fast after, never fast for a wrong password."""

from __future__ import annotations

import time

from roslink_mqtt.config.passwords import DEFAULT_ITERATIONS, VerifiedLogins, hash_password, verify_password


def test_new_hashes_use_todays_iteration_count_and_mosquittos_format() -> None:
    stored = hash_password("correct horse")
    assert stored.startswith(f"$7${DEFAULT_ITERATIONS}$") and DEFAULT_ITERATIONS >= 210_000
    assert verify_password("correct horse", stored)


def test_a_login_is_verified_slowly_once_then_fast_and_a_wrong_password_is_always_slow() -> None:
    stored = hash_password("correct horse", iterations=20_000)
    logins = VerifiedLogins()
    start = time.perf_counter()
    assert logins.verify("correct horse", stored)
    slow = time.perf_counter() - start
    start = time.perf_counter()
    for _ in range(20):
        assert logins.verify("correct horse", stored)
    fast = (time.perf_counter() - start) / 20
    assert (logins.slow, logins.fast) == (1, 20)
    assert fast < slow / 20, (fast, slow)  # a keyed SHA-256, not a PBKDF2
    for _ in range(3):
        assert not logins.verify("wrong horse", stored)
    assert logins.slow == 4  # every wrong password pays the full hash
    assert logins.verify("correct horse", stored) and logins.fast == 21  # still known after the wrong ones


def test_a_new_hash_for_the_login_is_verified_slowly_again_and_memory_is_bounded() -> None:
    logins = VerifiedLogins(max_entries=2)
    old, new = hash_password("old password", iterations=1000), hash_password("new password", iterations=1000)
    assert logins.verify("old password", old)
    assert not logins.verify("old password", new)  # the reload changed the hash: the old password is refused
    assert logins.verify("new password", new) and logins.slow == 3
    third = hash_password("third one", iterations=1000)
    assert logins.verify("third one", third)  # verified, though not remembered: the memory is full
    assert logins.verify("third one", third) and logins.slow == 5
