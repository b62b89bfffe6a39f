"""The serial line's options ([serial] keys) of the mode commands, the demotion of silent
addresses, and the SerialConfig they build."""
import click

from mbgw.cli.options import convert, parser, stack
from mbgw.config import model
from mbgw.config.schema import SerialOption
from mbgw.errors import ConfigError


def _check_device(path):
    """A path that can never be a serial device is refused (start, reload, check-config)."""
    from mbgw.config.device import device_problem
    if path is not None and (problem := device_problem(path)):
        raise ConfigError(problem)
    return path


def _device(ctx: click.Context, param: click.Parameter, value):
    """--device, checked; NO_DEVICE only from a slave-mode file that leaves [serial] out to
    its [[line]]s (mbgw.config.file.Settings.default_map): line serial does not run."""
    if value == model.NO_DEVICE and param.name is not None and \
            ctx.get_parameter_source(param.name) == click.core.ParameterSource.DEFAULT_MAP:
        return value
    return parser(_check_device)(ctx, param, value)


serial_options = stack(
    click.option("--device", cls=SerialOption, required=True, metavar="PATH",
                 callback=_device,
                 help="Serial device, e.g. /dev/ttyUSB0; one that is not there yet is "
                      "waited for."),
    click.option("--protocol", cls=SerialOption, type=click.Choice(model.PROTOCOLS),
                 default=model.SerialConfig.protocol, show_default=True,
                 help="Modbus framing on the serial line."),
    click.option("--baudrate", cls=SerialOption, type=click.IntRange(*model.BAUDRATE_RANGE),
                 default=model.SerialConfig.baudrate, show_default=True,
                 help="Line speed in bit/s, any rate from %d to %d." % model.BAUDRATE_RANGE),
    click.option("--format", "line_format", cls=SerialOption, default=str(model.LineFormat()),
                 show_default=True,
                 callback=parser(model.LineFormat.parse), metavar="NPS",
                 help="Data bits (7|8), parity (n|e|o|m|s: none, even, odd, mark, space), "
                      "stop bits (1|2)."),
    click.option("--interface", cls=SerialOption, default=str(model.Interface()),
                 show_default=True,
                 callback=parser(model.Interface.parse), metavar="KIND",
                 help="rs232; 'rs422 master' (or rs422), 'rs422 slave' (the transmitter on "
                      "only while sending, for multidrop); 'rs485 noecho' (or rs485) or "
                      "'rs485 echo' (the transceiver hears its own frames; they are dropped). "
                      "4wires is rs422, 2wires rs485."),
    click.option("--rtsdelays", cls=SerialOption,
                 type=(click.IntRange(*model.RTSDELAY_RANGE),
                       click.IntRange(*model.RTSDELAY_RANGE)),
                 default=model.SerialConfig.rtsdelays, show_default=True, metavar="BEFORE AFTER",
                 help="RS-485, an RS-422 slave or --rts modem: ms between raising RTS and "
                      "the first byte, and between the last byte and dropping RTS, 0..255."),
    click.option("--dtr", cls=SerialOption, type=click.Choice(model.DTR_MODES),
                 default=model.SerialConfig.dtr, show_default=True,
                 help="RS-232 DTR held high or low (a modem's on-line line)."),
    click.option("--rts", cls=SerialOption, type=click.Choice(model.RTS_MODES),
                 default=model.SerialConfig.rts, show_default=True,
                 help="RS-232 RTS: held high or low; flow: RTS/CTS flow control (with --cts "
                      "flow); modem: raised for each frame with --rtsdelays around it, a "
                      "radio modem's push-to-talk."),
    click.option("--cts", cls=SerialOption, type=click.Choice(model.CTS_MODES),
                 default=model.SerialConfig.cts, show_default=True,
                 help="RS-232 CTS: ignored, or flow: send only while CTS is up (with --rts "
                      "flow)."),
    click.option("--xonxoff", cls=SerialOption, type=click.Choice(model.XONXOFF_MODES),
                 default=model.SerialConfig.xonxoff, show_default=True,
                 help="XON/XOFF software flow control on the line: use or ignore."),
    click.option("--stout", cls=SerialOption, type=click.IntRange(*model.STOUT_RANGE),
                 default=model.DEFAULT_STOUT_MS, show_default=True, metavar="MS",
                 help="Time from the end of a request to the end of its answer, 1..65535 ms."),
    click.option("--silence", cls=SerialOption, type=click.IntRange(*model.SILENCE_RANGE),
                 default=model.SerialConfig.silence_ms, show_default=True,
                 metavar="MS",
                 help="RTU end-of-frame silence in ms, 0..65535 (0: the standard 3.5 "
                      "characters, 1.75 ms above 19200 bit/s); shorter gaps stay inside "
                      "a frame."),
    click.option("--ascii-timeout", cls=SerialOption,
                 type=click.IntRange(*model.ASCII_TIMEOUT_RANGE),
                 default=model.DEFAULT_ASCII_TIMEOUT_MS, show_default=True, metavar="MS",
                 help="ASCII: longest pause between two characters of a frame, 1..65535 ms."),
    click.option("--nocheck", cls=SerialOption, is_flag=True, default=model.SerialConfig.nocheck,
                 show_default=True,
                 help="Debugging only: forward serial replies unchecked (no CRC/LRC, "
                      "address or length control), as received until end of frame.  "
                      "[default: off]"),
)


# Demotion of silent serial addresses, the same rule in both modes ([serial] keys).
demotion_options = stack(
    click.option("--down-after", cls=SerialOption, type=click.IntRange(*model.DOWN_AFTER_RANGE),
                 default=model.DEFAULT_DOWN_AFTER, show_default=True, metavar="N",
                 help="A serial address is down after N requests in a row without a valid "
                      "reply; its requests are then refused at once (0x0B with --exception) "
                      "but for a probe per --probe-interval, until it answers.  0: never "
                      "down.  %d..%d." % model.DOWN_AFTER_RANGE),
    click.option("--probe-interval", cls=SerialOption,
                 type=click.IntRange(*model.PROBE_INTERVAL_RANGE),
                 default=model.DEFAULT_PROBE_INTERVAL_MS, show_default=True, metavar="MS",
                 help="While an address is down, one request per interval goes to it as a "
                      "probe; the interval doubles while the probes fail, up to %d ms.  "
                      "%d..%d ms." % (model.PROBE_BACKOFF_MAX_MS,
                                      *model.PROBE_INTERVAL_RANGE)),
)


def demotion(down_after: int, probe_interval: int) -> model.Demotion:
    return convert("'--down-after'", lambda: model.Demotion(down_after, probe_interval))


# Slave and master modes' (transparent mode's is its own, [transparent] silence).
interframe_option = click.option(
    "--interframe-silence", cls=SerialOption, type=click.IntRange(*model.INTERFRAME_SILENCE_RANGE),
    default=model.SerialConfig.interframe_ms, show_default=True, metavar="MS",
    help="VPGate's interframe silence: ms, beyond t3.5, that the line stays quiet after a "
         "frame before mbgw sends (slave mode: the next request after a reply; master mode: "
         "its answer after a request), 0..65535.")


def serial_config(device, protocol, baudrate, line_format, interface, rtsdelays, stout,
                   silence, ascii_timeout, nocheck, dtr="high", rts="high", cts="ignore",
                   xonxoff="ignore", interframe_silence=0) -> model.SerialConfig:
    try:
        return model.SerialConfig(
            device=device, protocol=protocol, baudrate=baudrate, format=line_format,
            interface=interface, rtsdelays=tuple(rtsdelays), stout_ms=stout,
            silence_ms=silence, ascii_timeout_ms=ascii_timeout, nocheck=nocheck, dtr=dtr,
            rts=rts, cts=cts, xonxoff=xonxoff, interframe_ms=interframe_silence)
    except ConfigError as err:
        option = str(err).split(" ", 1)[0]     # the message opens with the setting's name
        raise click.BadParameter(str(err), param_hint=f"'--{option}'") from None
