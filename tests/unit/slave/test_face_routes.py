"""The Modbus TCP face's routes at run time (mbgw.slave.routes): today's routing without
routes, the file's routes with the table's units kept, each unit's hop and rewrite."""
import dataclasses

from mbgw.config.lines import LineConfig, RouteConfig
from mbgw.config.model import SerialConfig, SlaveConfig, TableConfig
from mbgw.config.number_list import number_list_text as units_text
from mbgw.config.route_plan import routes_status
from mbgw.routing.queue import Inbox
from mbgw.slave.routes import (
    DIRECT,
    ELSEWHERE,
    SERIAL,
    TABLE,
    TO_TABLE,
    answered_off_the_line,
    effective_routes,
    face_hops,
    is_today,
)
from mbgw.slave.targets import line_settings

BASE = SlaveConfig(SerialConfig("/dev/ttyS0"))
TABLE_ON = dataclasses.replace(BASE, table=TableConfig(enabled=True))
METERS = LineConfig("meters", SerialConfig("/dev/ttyS1", baudrate=9600), retries=2)
TO_METERS = RouteConfig(2, tuple(range(32, 64)), line="meters", offset=-31)
TO_SERIAL = RouteConfig(1, tuple(range(1, 32)), line="serial")


def hops(cfg: SlaveConfig, inboxes=None):
    return face_hops(effective_routes(cfg), inboxes or {}, cfg.table_on)


def test_without_routes_every_unit_goes_todays_way():
    face = hops(BASE)
    assert len(face) == 256 and all(h is DIRECT for h in face)
    assert is_today(face) and not answered_off_the_line(face)


def test_the_tables_units_without_routes():
    face = hops(TABLE_ON)
    assert [u for u, h in enumerate(face) if h is TO_TABLE] == list(range(247, 255))
    assert all(h is DIRECT for u, h in enumerate(face) if not 247 <= u <= 254)
    assert is_today(face) and answered_off_the_line(face)     # the table reader runs
    no_direct = dataclasses.replace(TABLE_ON, table=TableConfig(enabled=True, direct=False))
    assert all(h is TO_TABLE for h in hops(no_direct))


def test_routes_take_their_units_and_the_rest_is_unrouted():
    cfg = dataclasses.replace(TABLE_ON, lines=(METERS,), routes=(TO_SERIAL, TO_METERS))
    inbox = Inbox()
    try:
        face = hops(cfg, {"meters": inbox})
        assert face[0] is None and face[64] is None and face[246] is None
        serial = face[1]
        assert serial is not None and serial.kind is SERIAL and serial.rewrite(31) == 31
        meters = face[32]
        assert meters is not None and meters.kind is ELSEWHERE and meters.inbox is inbox
        assert [meters.rewrite(u) for u in (32, 63)] == [1, 32]
        assert all(face[u] is TO_TABLE for u in range(247, 255))  # [table] units stay
        assert not is_today(face) and answered_off_the_line(face)
    finally:
        inbox.close()


def test_a_route_to_a_line_without_inbox_takes_nothing():
    cfg = dataclasses.replace(BASE, lines=(METERS,), routes=(TO_METERS,))
    assert hops(cfg)[32] is None


def test_rewrites_on_serial_and_the_table():
    fixed = RouteConfig(1, (10, 11), line="serial", address=17)
    table = RouteConfig(2, (200,), table=True, offset=-200)
    face = hops(dataclasses.replace(TABLE_ON, routes=(fixed, table)))
    assert face[10] is not None and face[10].kind is SERIAL and face[11].rewrite(11) == 17
    assert face[200] is not None and face[200].kind is TABLE and face[200].rewrite(200) == 0
    assert face[247] is None          # a route takes the table: [table] units are not added


def test_a_route_to_the_table_while_it_is_off_takes_nothing():
    face = hops(dataclasses.replace(BASE, routes=(RouteConfig(1, (5,), table=True),)))
    assert face[5] is None


def test_routes_as_status_lists_them():
    cfg = dataclasses.replace(TABLE_ON, lines=(METERS,), routes=(TO_METERS,))
    rows = routes_status(effective_routes(cfg))
    assert rows == [{"face": "tcp", "units": "247-254", "target": "table", "rewrite": "",
                     "implicit": True},
                    {"face": "tcp", "units": "32-63", "target": "line meters",
                     "rewrite": "offset -31", "implicit": False}]


def test_units_text():
    assert units_text((1, 2, 3, 7, 9, 10)) == "1-3,7,9-10"
    assert units_text(()) == ""


def test_a_target_lines_settings_are_its_own():
    cfg = dataclasses.replace(TABLE_ON, slaveid=5, lines=(METERS,), routes=(TO_METERS,))
    own = line_settings(cfg, METERS)
    assert own.serial.device == "/dev/ttyS1" and own.retries == 2 and own.slaveid == 0
    assert not own.table_on and not own.shortcut and not own.lines and not own.routes
