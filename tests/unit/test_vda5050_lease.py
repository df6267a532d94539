"""The order's lease (roslink_mqtt/vda5050/lease.py): an order gives back only the lease it took, so a master that
drives by ROSLink teleop between orders keeps its joystick."""

from __future__ import annotations

import pytest

from roslink_mqtt.vda5050.lease import LeaseStep, OrderLease

pytestmark = pytest.mark.unit


def test_an_order_takes_the_free_lease_and_gives_it_back_when_it_ends() -> None:
    lease = OrderLease("mes")
    assert lease.step(executing=True, holder=None) is LeaseStep.HOLD
    lease.held(True)
    assert lease.step(executing=True, holder="mes") is LeaseStep.NONE
    assert lease.step(executing=False, holder="mes") is LeaseStep.RELEASE
    lease.released()
    assert lease.step(executing=False, holder=None) is LeaseStep.NONE


def test_a_lease_the_master_already_held_is_not_the_orders_to_give_back() -> None:
    lease = OrderLease("mes")
    assert lease.step(executing=False, holder="mes") is LeaseStep.NONE  # the master's teleop, no order
    assert lease.step(executing=True, holder="mes") is LeaseStep.NONE  # an order under the master's own lease
    assert lease.step(executing=False, holder="mes") is LeaseStep.NONE  # it ends: the teleop lease stays


def test_a_refused_hold_or_a_lease_lost_mid_order_is_not_given_back_later() -> None:
    lease = OrderLease("mes")
    assert lease.step(executing=True, holder=None) is LeaseStep.HOLD
    lease.held(False)  # fenced: the endpoint refused
    assert lease.step(executing=False, holder="mes") is LeaseStep.NONE
    lease.step(executing=True, holder=None)
    lease.held(True)
    assert lease.step(executing=True, holder="alice") is LeaseStep.NONE  # stopped, and alice took over
    assert lease.step(executing=True, holder="mes") is LeaseStep.NONE  # later the master's own claim
    assert lease.step(executing=False, holder="mes") is LeaseStep.NONE  # … is not the order's
    assert lease.step(executing=True, holder="bob") is LeaseStep.NONE  # somebody else's lease: never taken over
