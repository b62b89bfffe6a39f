"""The serial line, for both modes; with `table` the only part that touches the C core (mbgw._ffi).

`native` wraps the serial port's C calls (libmodbus's RTU context plus csrc/: timed reads,
writes with RTS, the reply forward); `frames` the frame rules (CRC, LRC, lengths, ASCII, does
a reply answer); `clients` slave mode's client reads dated by the kernel; `port.SerialLine`
opens the tty with every setting and puts frames on it; `framing` sends and receives one ADU
in RTU or ASCII; `supervisor` is the skeleton of a line thread that both modes run (reopen a
lost device, take new settings between transactions).  On a request's path: slave mode's
transaction calls framing to send it and read the reply; master mode's line thread calls it
to read a request and write the answer."""
