"""The `mbgw transparent` command: Modbus TCP clients exchange raw frames with a serial device
that speaks no Modbus, through the exchange table served on mdbport (VPGate 3.8)."""
import click

from mbgw.cli.daemon_options import daemon_options, scenario_tcpto_option
from mbgw.cli.options import ModeCommand, authip_option, bind_option, convert
from mbgw.cli.run import run_daemon
from mbgw.cli.serial_options import serial_config, serial_options
from mbgw.cli.table_options import table_max_connections_option
from mbgw.cli.tls_options import tls_config, tls_options
from mbgw.config import model
from mbgw.config.schema import TransparentOption
from mbgw.config.transparent import (
    EOF_CHAR_RANGE,
    EOF_KINDS,
    EOF_TIMEOUT_RANGE,
    FRAME_SIZE_RANGE,
    RX_ADDRESS_RANGE,
    TX_ADDRESS_RANGE,
    TransparentConfig,
    TransparentModeConfig,
)

_DEFAULTS = TransparentConfig()


def _option(flag: str, key: str, **kwargs):
    return click.option(flag, cls=TransparentOption, key=key, show_default=True, **kwargs)


@click.command(cls=ModeCommand)
@serial_options
@authip_option("Client address allowed to connect to mdbport and raw-port (repeat, at most "
               "8; none: anyone).")
@click.option("--mdbport", type=click.IntRange(*model.MDBPORT_RANGE),
              default=model.DEFAULT_MDBPORT, show_default=True,
              help="Modbus TCP port where clients reach the exchange table (every unit id; "
                   "unit 0 is a broadcast write); 0: TLS only (--tls-cert).")
@bind_option()
@scenario_tcpto_option
@_option("--eof", "eof", type=click.Choice(EOF_KINDS), default=_DEFAULTS.eof,
         help="How a frame ends: an end character (nul, space, lf, cr, crlf, lfcr; char: "
              "--eof-char), length (the first byte counts the bytes after it) or timeout "
              "(--eof-timeout of silence).")
@_option("--eof-char", "eof-char", type=click.IntRange(*EOF_CHAR_RANGE),
         default=_DEFAULTS.eof_char, metavar="N",
         help="With --eof char: the end character's code, 0..255.")
@_option("--eof-timeout", "eof-timeout", type=click.IntRange(*EOF_TIMEOUT_RANGE),
         default=_DEFAULTS.eof_timeout_ms, metavar="MS",
         help="Silence that ends a frame (--eof timeout) or drops an incomplete one, 0..65535 "
              "ms; 0: the serial line's end-of-frame silence (--silence, else t3.5).")
@_option("--rx-address", "rx-address", type=click.IntRange(*RX_ADDRESS_RANGE),
         default=_DEFAULTS.rx_address, metavar="N",
         help="Register where received frames are stored (the inputs, 0..2047).")
@_option("--rx-size", "rx-size", type=click.IntRange(*FRAME_SIZE_RANGE),
         default=_DEFAULTS.rx_size, metavar="BYTES",
         help="Bytes of the rx area, two to a register (1..250); longer frames are cut.")
@_option("--tx-address", "tx-address", type=click.IntRange(*TX_ADDRESS_RANGE),
         default=_DEFAULTS.tx_address, metavar="N",
         help="Register of the tx area: a change there sends its frame (the outputs, "
              "2048..4095).")
@_option("--tx-size", "tx-size", type=click.IntRange(*FRAME_SIZE_RANGE),
         default=_DEFAULTS.tx_size, metavar="BYTES", help="Bytes of the tx area (1..250).")
@_option("--crc/--no-crc", "crc", default=_DEFAULTS.crc,
         help="A CRC-16/MODBUS follows each frame on the line: checked (a wrong one drops "
              "the frame) and added to sent frames; the table holds frames without it.")
@_option("--trigger/--no-trigger", "trigger", default=_DEFAULTS.trigger,
         help="The areas' first byte is a frame counter: raised for each frame stored; a new "
              "value in the tx area sends its frame, other changes send nothing.")
@_option("--interframe-silence", "transparent-silence", file_key="silence",
         type=click.IntRange(*model.INTERFRAME_SILENCE_RANGE),
         default=_DEFAULTS.silence_ms, metavar="MS",
         help="After a frame was received, wait this long before sending, 0..65535 ms.")
@_option("--raw-port", "raw-port", type=click.IntRange(*model.PORT_RANGE), default=None,
         help="TCP port giving one client the line as a byte stream (a second is refused) "
              "[default: off].")
@table_max_connections_option(
    "TCP clients of the table at once (mdbport's and the TLS port's); a newcomer beyond it "
    "takes the place of one that sent no request yet, or is refused.")
@tls_options
@daemon_options
def transparent(**options) -> None:
    """Transparent mode: Modbus TCP clients exchange raw frames with a serial device through
    the exchange table."""
    from mbgw.gateway.daemon import run_transparent_mode

    run_daemon(run_transparent_mode, transparent_config, options)


def transparent_config(device, protocol, baudrate, line_format, interface, rtsdelays, stout,
                       silence, ascii_timeout, nocheck, dtr, rts, cts, xonxoff, authip, mdbport,
                       bind, eof, eof_char, eof_timeout, rx_address, rx_size, tx_address, tx_size,
                       crc, trigger, interframe_silence, raw_port, control, metrics,
                       table_max_connections=model.DEFAULT_TABLE_MAX_CONNECTIONS,
                       log_level=None, firewall=None, scenarios=(), tcpto=model.DEFAULT_TCPTO_MS,
                       tls_port=model.DEFAULT_TLS_PORT, tls_cert=None, tls_key=None, tls_ca=None,
                       tls_require_role=True, tls_crl=None) -> TransparentModeConfig:
    serial = serial_config(device, protocol, baudrate, line_format, interface, rtsdelays,
                            stout, silence, ascii_timeout, nocheck, dtr, rts, cts, xonxoff)
    frames = convert("'--rx-address' / '--tx-address'", lambda: TransparentConfig(
        eof=eof, eof_char=eof_char, eof_timeout_ms=eof_timeout, rx_address=rx_address,
        rx_size=rx_size, tx_address=tx_address, tx_size=tx_size, crc=crc, trigger=trigger,
        silence_ms=interframe_silence, raw_port=raw_port))
    tls = tls_config(tls_port, tls_cert, tls_key, tls_ca, tls_require_role, tls_crl)
    return convert(None, lambda: TransparentModeConfig(
        serial=serial, transparent=frames, authip=authip, mdbport=mdbport, bind=bind,
        control=control, metrics=metrics, firewall=firewall, scenarios=scenarios,
        tcpto_ms=tcpto, tls=tls, table=model.TableConfig(
            enabled=True, direct=False, max_connections=table_max_connections)))


transparent.make_config = transparent_config
