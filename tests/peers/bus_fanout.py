"""A shared serial bus made of ptys: what any end writes, every other end reads, as on an
RS-485 pair, and who wrote what is recorded.

usage: bus_fanout.py LINK... --record PATH

Each LINK becomes a symlink to a pty of its own (raw, held open here so that it lives while
its user reopens it).  Every read from a pty's master (what that end's user wrote) is written
to the other ptys' masters and recorded as "<LINK's name> <hex>", flushed at once.  Prints
READY, then nothing on stdout; runs until killed."""
import argparse
import os
import select
import tty
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("links", nargs="+")
    parser.add_argument("--record", required=True)
    args = parser.parse_args()
    ends: dict[int, str] = {}
    for link in args.links:
        master, slave = os.openpty()
        tty.setraw(slave)
        Path(link).unlink(missing_ok=True)
        os.symlink(os.ttyname(slave), link)
        ends[master] = Path(link).name
    poll = select.poll()
    for fd in ends:
        poll.register(fd, select.POLLIN)
    with open(args.record, "w", buffering=1) as record:
        print("READY", flush=True)
        while True:
            for fd, _ in poll.poll():
                try:
                    data = os.read(fd, 4096)
                except OSError:         # its user closed it: nobody writes there now
                    continue
                record.write(f"{ends[fd]} {data.hex()}\n")
                for other in ends:
                    if other != fd:
                        os.write(other, data)


if __name__ == "__main__":
    main()
