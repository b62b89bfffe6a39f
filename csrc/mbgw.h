/* mbgw's own C: what Debian's libmodbus 3.1.6 lacks.  This header is also the cffi cdef,
 * so it holds only prototypes and plain #defines (no #include, no #if).
 * A function that can fail returns a negative errno value when it does (not -1 with errno
 * set), except mbgw_send_rtu, which follows libmodbus.  The others return what their
 * comment says: the CRC, a length, a verdict, a generation, or nothing. */

struct _modbus; /* libmodbus's modbus_t */

#define MBGW_RTU_MAX_ADU 256     /* Modbus over Serial Line V1.02 section 2.5.1 */
#define MBGW_LEN_UNKNOWN -1      /* the frame's end can only be found by silence */
#define MBGW_ASCII_MAX_FRAME 513 /* characters, ':' to LF included (V1.02 2.5.2.1) */

/* CRC-16/MODBUS (reflected poly 0xA001, init 0xFFFF); sent low byte first. */
uint16_t mbgw_crc16(const uint8_t *buf, size_t len);

/* LRC of an ASCII frame: the two's complement of the 8-bit sum of its bytes. */
uint8_t mbgw_lrc(const uint8_t *buf, size_t len);

/* adu (address to data, no LRC) as ':' HEX LRC CR LF, upper case.  Returns the length. */
int mbgw_ascii_encode(const uint8_t *adu, size_t len, uint8_t *out, size_t cap);

/* A whole ASCII frame (':' to LF) back to address..data; hex of either case accepted.
 * -EBADMSG malformed, -EILSEQ wrong LRC, -EMSGSIZE too long. */
int mbgw_ascii_decode(const uint8_t *frame, size_t len, uint8_t *adu, size_t cap);

/* Total RTU ADU length (address and CRC included) of the reply to a request of req_len
 * bytes (an ADU without CRC), judged from the first `have` bytes of the reply: > 0 the
 * length, 0 more bytes are needed to tell, MBGW_LEN_UNKNOWN for function codes whose
 * length only silence can tell. */
int mbgw_rtu_reply_length(size_t req_len, const uint8_t *rsp, size_t have);

/* The same for a request (master mode receives requests for several addresses). */
int mbgw_rtu_request_length(const uint8_t *req, size_t have);

/* --- line.c: timed reads and writes on the tty's fd --- */

/* Read and discard input until the line has been quiet for quiet_us since last_ns
 * (CLOCK_MONOTONIC).  Returns the number of bytes discarded.  (No tcflush: it would drop,
 * uncounted, a frame that arrived after the quiet period.) */
long mbgw_wait_quiet(int fd, int64_t last_ns, int32_t quiet_us);

/* Sleep until wake_fd (an eventfd) is signalled, input arrives on fd, or timeout_ms
 * passes (-1: no timeout).  Returns one of MBGW_IDLE_*. */
#define MBGW_IDLE_WOKEN 0 /* wake_fd was signalled (its count is read) */
#define MBGW_IDLE_INPUT 1 /* input waits on fd */
#define MBGW_IDLE_TIMEOUT 2
int mbgw_idle_wait(int fd, int wake_fd, int timeout_ms);

/* nocheck's receive: whatever comes, unchecked, into buf.  The first byte must arrive
 * before deadline_ns; after it, gap_us of silence ends the frame, complete or not (or cap
 * bytes do).  *end_ns receives the time the last byte arrived.  Returns the bytes read or
 * -ETIMEDOUT when nothing came. */
long mbgw_read_reply(int fd, uint8_t *buf, size_t cap, int64_t deadline_ns,
                     int32_t gap_us, int64_t *end_ns);

/* Slave mode: read what the line carries after the request req (address + PDU, CRC
 * excluded), at most cap bytes, until it holds a frame, and put that frame at buf[0]. The
 * first byte must come before deadline_ns; after it, gap_us of silence ends the burst.  A
 * burst that begins with a whole frame with a valid CRC (any address, length by its
 * function code) gives that frame, and no byte behind it is read (it is the next call's).
 * Otherwise the reply is looked for behind what cannot start it, at each following
 * offset: req's address, its function or that exception, the length its byte count or
 * function code gives (else the rest of the burst), a valid CRC, and mbgw_reply_matches.
 * *noise: the bytes read that are not the frame returned; *end_ns: when the last byte
 * came (nothing came: when the wait ended).  Returns the frame's length with CRC;
 * -ETIMEDOUT nothing came; a burst without a frame: -EILSEQ the reply by its start and
 * length but a bad CRC, -EMSGSIZE cap bytes, -EBADMSG anything else. */
long mbgw_find_reply(int fd, uint8_t *buf, size_t cap, const uint8_t *req, size_t req_len,
                     int64_t deadline_ns, int32_t gap_us, int64_t *end_ns, int *noise);

/* Read one ASCII frame (':' to CR LF) into buf.  The ':' must come before deadline_ns,
 * each following character within interchar_us of the previous one, the whole frame
 * before deadline_ns; a ':' restarts the frame.  *noise: the bytes read that are not the
 * frame returned (before its ':', a frame it restarted, all of them on an error).
 * -ETIMEDOUT no ':' came, -EBADMSG incomplete, -EMSGSIZE longer than
 * MBGW_ASCII_MAX_FRAME. */
long mbgw_ascii_read_frame(int fd, uint8_t *buf, size_t cap, int64_t deadline_ns,
                           int32_t interchar_us, int64_t *end_ns, int *noise);

/* Write the whole frame.  With rts_control, raise RTS before_us before the first byte and
 * drop it after_us after the last one has left the UART (tcdrain), for RS-485
 * transceivers whose driver has no kernel RS-485 mode. */
int mbgw_write_frame(int fd, const uint8_t *buf, size_t len, int rts_control,
                     int32_t before_us, int32_t after_us);

/* Read back and drop the echo of the frame just sent (2-wire RS-485 with the receiver
 * on). -EPROTO when the echo differs (a collision), -ETIMEDOUT when it does not come. */
int mbgw_discard_echo(int fd, const uint8_t *sent, size_t len, int64_t deadline_ns);

/* --- tty.c: the tty itself: its claim, settings libmodbus cannot make, RTS --- */

/* Open path and take an advisory flock on it, before anything touches the line's
 * settings: a second gateway is refused without disturbing the first.  Then, before
 * anything else, DTR (dtr_low) and RTS (rts_low) are lowered: the open raised them, as it
 * does for any tty at a non-zero speed, and a transmitter keyed by them must not stay on
 * (a tty without modem lines, a pty, is left as it is).  Returns the fd (kept open as
 * long as the line is used) or -EBUSY when another program holds the lock. */
int mbgw_tty_lock(const char *path, int dtr_low, int rts_low);

/* TIOCEXCL: no further opens of the tty (except by root, whom the flock stops). */
int mbgw_tty_claim(int fd);

/* Undo mbgw_tty_claim before closing: TIOCEXCL outlives our fd on a tty that another
 * process (socat, getty) keeps open, and would refuse our own restart. */
int mbgw_tty_release(int fd);

/* cflag with the size, parity (n e o m s) and stop bits of a line format set. */
uint32_t mbgw_tty_cflag(uint32_t cflag, int data_bits, char parity, int stop_bits);
int mbgw_tty_set_format(int fd, int data_bits, char parity, int stop_bits);

/* Any rate, through termios2 and BOTHER. */
int mbgw_tty_set_baud(int fd, uint32_t baud);

/* The cflag and output rate the kernel holds for fd. */
int mbgw_tty_get(int fd, uint32_t *cflag, uint32_t *baud);

/* ASYNC_LOW_LATENCY: USB adapters then hand over bytes at once instead of every 16 ms. */
int mbgw_tty_low_latency(int fd);

/* Kernel RS-485: RTS drives the transmitter during each frame, with delays around it.
 * -ENOTTY (or -EINVAL) when the driver has no RS-485 support. */
int mbgw_tty_rs485(int fd, int before_ms, int after_ms, int rx_during_tx);

/* 0 when the modem lines (RTS) can be driven on fd, else -errno. */
int mbgw_rts_available(int fd);

/* Set DTR and RTS high (1) or low (0), or leave them (-1); -errno when the tty has no
 * modem control lines (a pty: -ENOTTY or -EINVAL). */
int mbgw_tty_modem_lines(int fd, int dtr, int rts);

/* RTS/CTS (CRTSCTS) and XON/XOFF (IXON, IXOFF) flow control on (1) or off (0). */
int mbgw_tty_flow(int fd, int rtscts, int xonxoff);

/* Call first in the thread that owns the line: its timers then fire on time. */
int mbgw_line_thread_init(void);

/* Name the calling thread (at most 15 bytes) for ps -L, top -H and /proc/PID/task. */
int mbgw_name_thread(const char *name);

/* --- match.c: does a reply answer its request (no I/O) --- */

/* 1 when the reply PDU rsp can be the answer to the request PDU req: an exception for the
 * request's function, or its function with the size or echo the request asked for. */
int mbgw_reply_matches(const uint8_t *req, size_t req_len, const uint8_t *rsp,
                       size_t rsp_len);

/* Master mode: what a server's Modbus TCP reply is to the request PDU req sent to unit.
 * rsp: its PDU, as long as its MBAP length says; rsp_unit: its unit id.  The PDU's own
 * length (function code, byte count) must be the MBAP length's, the unit id the one sent,
 * and the PDU must pass mbgw_reply_matches.  Returns one of MBGW_REPLY_*. */
#define MBGW_REPLY_ANSWERS 0
#define MBGW_REPLY_BAD_LENGTH 1 /* the MBAP length and the PDU disagree */
#define MBGW_REPLY_WRONG_UNIT 2
/* another function, or a size or echo not asked for */
#define MBGW_REPLY_WRONG_FUNCTION 3
int mbgw_tcp_reply_verdict(const uint8_t *req, size_t req_len, uint8_t unit,
                           uint8_t rsp_unit, const uint8_t *rsp, size_t rsp_len);

/* --- mbap.c: the MBAP header of Modbus TCP --- */

/* The length of the frame (header included) whose MBAP header holds protocol id protocol
 * and the length field length (unit id + PDU): 6 + length.  -EPROTO the protocol id is
 * not 0 (not Modbus), -EMSGSIZE the length is outside 2..254. */
int mbgw_mbap_frame_len(unsigned protocol, unsigned length);

/* --- forward.c: slave mode's replies to the client's socket, requests to the line --- */

/* Where mbgw_receive_reply puts the ADU: behind the first 6 bytes of an MBAP header, so
 * the address byte sits where the unit id goes. */
#define MBGW_REPLY_AT 6
/* The bytes behind MBGW_REPLY_AT a receive may read: a whole frame after as much
 * noise. */
#define MBGW_REPLY_SCAN 512

/* Where a reply that answers its request goes at once: the client's socket (fd < 0:
 * nowhere), with the client's transaction id and unit id.  in_flight (or NULL): the
 * client's count of requests in the gateway, decremented as the reply is handed over, so
 * that the client is idle again the moment it can see its reply.  yield_cpu: then give
 * the CPU to the client that was woken before returning (nothing else waits for the
 * line). */
struct mbgw_forward {
    int fd;
    uint16_t tid;
    uint8_t unit;
    uint8_t yield_cpu;
    int *in_flight;
};

/* mbgw_find_reply of the reply to req (address + PDU, no CRC) until deadline_ns (gap_us:
 * the end-of-frame silence), into buf + MBGW_REPLY_AT (buf holds MBGW_REPLY_AT +
 * MBGW_REPLY_SCAN bytes).  When the frame is from req's address and answers req
 * (mbgw_reply_matches), came in time and to->fd >= 0, it goes to that socket at once as a
 * Modbus TCP frame, and *forwarded is the bytes the socket took (all of them when the
 * connection is broken: its next read tells); else *forwarded is -1.  *end_ns, *noise:
 * mbgw_find_reply's. Returns the frame's length with CRC (any address), or
 * mbgw_find_reply's negative errno; -EBADF ctx has no line open. */
int mbgw_receive_reply(struct _modbus *ctx, uint8_t *buf, const uint8_t *req,
                       size_t req_len, int64_t deadline_ns, int32_t gap_us,
                       const struct mbgw_forward *to, int64_t *end_ns, int *forwarded,
                       int *noise);

/* libmodbus's send of req (it adds the CRC), then mbgw_receive_reply with the deadline
 * stout_ns after the request's last byte, in one call: the thread sleeps the moment the
 * request is written.  times[0]: when the request's last byte leaves (char_ns a
 * character); times[1]: mbgw_receive_reply's *end_ns.  Returns mbgw_receive_reply's
 * result; when the request could not be written, the write's negative errno with
 * times[0] 0 (nothing left, nothing read). */
int mbgw_exchange(struct _modbus *ctx, uint8_t *buf, const uint8_t *req, size_t req_len,
                  int64_t char_ns, int64_t stout_ns, int32_t gap_us,
                  const struct mbgw_forward *to, int64_t *times, int *forwarded,
                  int *noise);

/* SO_TIMESTAMPNS on a socket (a listening one: on every connection it accepts too): the
 * kernel then dates what arrives, for mbgw_client_recv. */
int mbgw_stamp_arrivals(int fd);

/* recv() of up to cap bytes from a client's socket, not waiting, and *arrived_ns: when
 * they arrived (CLOCK_MONOTONIC), by the kernel's receive timestamp of the newest segment
 * read (SO_TIMESTAMPNS), else now.  Returns the bytes read, 0 at the connection's end,
 * -EAGAIN when nothing waits, another negative errno. */
long mbgw_client_recv(int client_fd, uint8_t *buf, size_t cap, int64_t *arrived_ns);

#define MBGW_MAX_ADDRESS 247 /* the highest unicast serial address */

/* What a request must meet to take the shortcut to the line, and what came of it. */
struct mbgw_shortcut {
    const uint8_t *framed; /* 256 flags: the function codes libmodbus frames */
    const uint8_t *down;   /* 256 flags: the serial addresses that are down (demoted) */
    const int64_t *late_until; /* by address: the end of its late window (0: none) */
    const uint8_t *own; /* 256 flags: addresses with timing of their own ([[device]]) */
    int64_t quiet_until_ns; /* the line must stay silent until then */
    int64_t char_ns;
    int64_t stout_ns;
    int32_t gap_us;     /* the end-of-frame silence */
    uint8_t slaveid;    /* the serial address of every request; 0: the unit id */
    int taken;          /* out: 1 the request went on the line, 0 it is the caller's */
    int result;         /* out: when taken, mbgw_exchange's return */
    int64_t times[2];   /* out: when taken, mbgw_exchange's */
    int forwarded;      /* out: when taken, mbgw_exchange's */
    int noise;          /* out: mbgw_exchange's */
    uint8_t address;    /* out: the serial address the request went to */
    int64_t arrived_ns; /* out: when what was read arrived (mbgw_client_recv) */
};

/* Slave mode, a client readable while the line is idle: read what it sent (up to in_cap
 * bytes) into in (mbgw_client_recv).  When that is exactly one Modbus TCP request with a
 * valid header, a function code marked in sc->framed, and a serial address
 * 1..MBGW_MAX_ADDRESS not marked in sc->down (the caller refuses those requests, or sends
 * one as the probe), nor in sc->own (timing of its own), nor in its late window
 * (sc->late_until), and the line
 * has been silent until sc->quiet_until_ns, the request goes on the line at once
 * (mbgw_exchange, its reply forwarded to client_fd, which then runs first, and in_flight
 * decremented as it is) and sc->taken is 1; the caller keeps the books.  Otherwise
 * sc->taken is 0 and the bytes are the caller's to frame.
 * Returns the bytes read, 0 when the connection has ended, -EAGAIN when nothing came, or
 * another negative errno. */
int mbgw_take_request(struct _modbus *ctx, int client_fd, int *in_flight, uint8_t *in,
                      size_t in_cap, uint8_t *buf, struct mbgw_shortcut *sc);

/* --- remote.c: a remote line's exchange on Modbus TCP --- */

/* What mbgw_remote_send and mbgw_remote_reply did besides the reply. */
struct mbgw_remote {
    int64_t sent_ns; /* when the request was sent (0: it was not) */
    int64_t end_ns;  /* when the last byte read came (timed out: when the wait ended) */
    int at;          /* where the reply's MBAP header begins in buf */
    int received;    /* the bytes read after the send */
    int stale;       /* the bytes waiting before the send, read and dropped */
    int strays;      /* whole frames that did not answer the request, dropped */
    int noise;       /* the bytes from a header that frames nothing to the end */
    int left;        /* the bytes read behind the reply, dropped */
    int forwarded;   /* the bytes of the reply the client's socket took (-1: not sent) */
};
/* Slave mode, a device across the network: drop what waits on the connected socket fd
 * (no request is outstanding) and send the request req (address + PDU) in one Modbus TCP
 * frame with transaction id tid (buf: cap bytes, at least MBGW_MBAP_MAX, for what is
 * dropped).  Returns 0 (r->sent_ns: when), or the request was not sent: -ENOTCONN the
 * device had closed the connection, -EAGAIN the socket took only part of it, -EINVAL
 * req_len outside 2..254 or cap too small, another send's -errno. */
int mbgw_remote_send(int fd, uint8_t *buf, size_t cap, const uint8_t *req, size_t req_len,
                     unsigned tid, struct mbgw_remote *r);
/* After mbgw_remote_send of req with tid: read fd into buf until a frame answers req or
 * deadline_ns passes.  Frames are cut by their MBAP length (mbgw_mbap_frame_len); one
 * answers when it has tid, protocol id 0, req's address as its unit id and a PDU that
 * answers req's (mbgw_tcp_reply_verdict); any other whole frame is dropped (r->strays).
 * The reply found goes at once to to->fd when to is not NULL and to->fd >= 0, under
 * to's transaction id and unit id (struct mbgw_forward; r->forwarded: the bytes the
 * socket took).  Returns the reply's length, MBAP header included, at buf + r->at;
 * -ETIMEDOUT no reply in time (a frame begun is dropped), -ENOTCONN the device closed the
 * connection, -EPROTO a header that frames nothing (the stream is out of step), -EIO or
 * another -errno the connection failed. */
int mbgw_remote_reply(int fd, uint8_t *buf, size_t cap, const uint8_t *req,
                      size_t req_len, unsigned tid, int64_t deadline_ns,
                      const struct mbgw_forward *to, struct mbgw_remote *r);
/* mbgw_remote_send, then mbgw_remote_reply until stout_ns after the send, in one call;
 * mbgw_remote_send's error when the request was not sent (r->sent_ns 0). */
int mbgw_remote_exchange(int fd, uint8_t *buf, size_t cap, const uint8_t *req,
                         size_t req_len, unsigned tid, int64_t stout_ns,
                         const struct mbgw_forward *to, struct mbgw_remote *r);

/* A client lent to a remote line's thread (Modbus TCP): what its next request must meet
 * to go to the line at once, and the request taken. */
struct mbgw_loan {
    const uint8_t *units; /* 256: the address each unit id has on this line; 0: not its */
    const uint8_t *down;  /* 256 flags: the addresses that are down (demoted) */
    int64_t arrived_ns;   /* out: when the request arrived (mbgw_client_recv) */
    uint16_t tid;         /* out: the client's transaction id */
    uint8_t unit;         /* out: the client's unit id */
    int send_error;       /* out: mbgw_remote_send's result (0: the request went) */
    int adu_len;          /* out: the request as it went on the line: address + PDU */
    uint8_t adu[254];
};
/* A lent client readable: when what waits on client_fd is exactly one Modbus TCP request
 * with a valid header whose unit id loan->units maps to an address that is not down, read
 * it (mbgw_client_recv), count it in *in_flight (or NULL) and send it on the line
 * (mbgw_remote_send with tid; r tells whether it went), and return 1: the caller then
 * waits for its reply with mbgw_remote_reply.  Otherwise nothing is read: 0 (anything
 * else waits, or the connection has ended), -EAGAIN nothing waits, another -errno. */
int mbgw_remote_take(int client_fd, int *in_flight, int line_fd, uint8_t *buf, size_t cap,
                     unsigned tid, struct mbgw_loan *loan, struct mbgw_remote *r);

/* --- request.c: master mode, the serial master's requests for any address --- */

/* Wait (no deadline) for a frame on fd, then read it into buf: framed by the request
 * length of its function code, or by the reply length when it comes from reply_to's
 * address (the last frame for a slave mbgw does not answer for; reply_to_len 0: none),
 * the first length whose CRC checks; else by gap_us of silence (a frame behind noise is
 * then looked for at the end of that burst).  Never reads past the frame.  Returns its
 * length with the CRC (valid).  -ECANCELED wake_fd was signalled, or idle_ms (-1: no
 * limit) passed, before a frame began; -EILSEQ bad CRC, -EBADMSG too short, -EMSGSIZE
 * longer than cap. */
long mbgw_rtu_read_request(int fd, int wake_fd, uint8_t *buf, size_t cap,
                           const uint8_t *reply_to, size_t reply_to_len, int32_t gap_us,
                           int idle_ms);

/* --- table.c: the exchange table's memory; table_answer.c: its Modbus server --- */

#define MBGW_PDU_MAX 253  /* Modbus Application Protocol V1.1b3, 4.1 */
#define MBGW_MBAP_MAX 260 /* the MBAP header (7 bytes) and the largest PDU */

/* 65,536 registers of 16 bits, a mutex and the counters; zones: inputs 0x0000-0x07FF,
 * outputs 0x0800-0x0FFF, free 0x1000-0x7FFF, configuration 0x8000-0xFFFF (read-only but
 * to mbgw_table_set_config).  Bit B of the bit functions is bit B % 16 (0 = LSB) of
 * register B / 16. */
typedef struct mbgw_table mbgw_table;

/* All registers zero, every function the table knows (1-7, 15, 16, 23) answered; NULL
 * when out of memory. */
mbgw_table *mbgw_table_new(void);
void mbgw_table_free(mbgw_table *t);

/* Bit n set: function code n is answered (only those the table knows count); any other is
 * exception 0x01. */
void mbgw_table_set_functions(mbgw_table *t, uint32_t mask);

/* Answer one request PDU req (function code first, len bytes) into rsp (MBGW_PDU_MAX
 * bytes): returns the reply PDU's length (a normal reply or exception 0x01, 0x02, 0x03),
 * or 0 when broadcast != 0 (writes done, reads ignored, nothing to send) or len < 1.
 * The identity functions (below) are answered whatever the function mask says.
 * Checks in the order: function unknown or disabled 0x01; quantity outside the Modbus
 * limits, byte count or PDU length that does not match, FC 5 value not 0x0000/0xFF00
 * 0x03; address + quantity beyond 65,536 or a write into the configuration zone 0x02
 * (nothing written).  The whole request runs under the table's lock. */
int mbgw_table_answer(mbgw_table *t, const uint8_t *req, int len, uint8_t *rsp,
                      int broadcast);

/* The same for a whole Modbus TCP frame (7-byte MBAP header + PDU) into rsp
 * (MBGW_MBAP_MAX bytes): the reply with the request's transaction id and unit id,
 * protocol id 0 and its length field.  Returns its length, 0 for no reply, -EBADMSG when
 * the header frames nothing (mbgw_mbap_frame_len) or another length than the frame's. */
int mbgw_table_answer_mbap(mbgw_table *t, const uint8_t *adu, int len, uint8_t *rsp,
                           int broadcast);

/* The identity functions, answered whatever mbgw_table_set_functions says: FC 8
 * (sub-functions 0 and 10-18), FC 17 and FC 43/14 (conformity 0x83, objects 0-6).
 * mbgw_table_set_identity sets object `object` (0-6) of FC 43/14,
 * mbgw_table_set_server_id FC 17's bytes after the byte count; -EINVAL out of bounds.
 * mbgw_table_count_refused counts a request refused before the table saw it (0x01, or
 * nothing for a broadcast), mbgw_table_count_bad_frame a frame for it that framed nothing
 * (a bad CRC or length on a serial line); mbgw_table_diagnostics copies FC 8's counters
 * 11-18 (8). */
#define MBGW_IDENT_OBJECTS 7
#define MBGW_IDENT_OBJECT_MAX 244 /* one object alone fills a reply: 253 - 7 - 2 */
#define MBGW_SERVER_ID_MAX 251    /* 253 - FC - byte count */
int mbgw_table_set_identity(mbgw_table *t, int object, const uint8_t *value, int len);
int mbgw_table_set_server_id(mbgw_table *t, const uint8_t *data, int len);
void mbgw_table_count_refused(mbgw_table *t, int broadcast);
void mbgw_table_count_bad_frame(mbgw_table *t);
void mbgw_table_diagnostics(mbgw_table *t, uint16_t *out);

/* count registers from address into out; -EINVAL beyond the table. */
int mbgw_table_read(mbgw_table *t, int address, int count, uint16_t *out);

/* count registers from address from in; -EINVAL beyond the table, -EPERM (-1) when they
 * touch the configuration zone (nothing written). */
int mbgw_table_write(mbgw_table *t, int address, int count, const uint16_t *in);

/* The configuration zone's content; registers outside 0x8000-0xFFFF: nothing written. */
void mbgw_table_set_config(mbgw_table *t, int address, int count, const uint16_t *in);

/* Every write marks its registers written (a bit write its register), whatever the value:
 * Modbus requests, the operator's writes, scenario reads, persistence, the configuration
 * zone.  The first register of [first, first + count) never written since the table was
 * made, -1 when all were, -EINVAL beyond the table.  Write scenarios send only written
 * data. */
int mbgw_table_unwritten(mbgw_table *t, int first, int count);

/* FC 7's status byte: bit 0 the serial line is down, bit 1 a scenario is in error, bit 2
 * a device is down. */
void mbgw_table_set_flags(mbgw_table *t, int line_down, int scenario_error);
/* One of them alone (the line thread and the scenarios each own one). */
#define MBGW_TABLE_LINE_DOWN 0
#define MBGW_TABLE_SCENARIO_ERROR 1
void mbgw_table_set_flag(mbgw_table *t, int flag, int on);
/* Bit 2's source: down (256 flags by serial address, the caller's, NULL: none) is read at
 * each FC 7. */
void mbgw_table_watch_down(mbgw_table *t, const uint8_t *down);

/* count bits from bit address `bit` (bit B: bit B % 16 of register B / 16), packed as in
 * a Modbus PDU (the first in the least significant bit of packed[0]), under the lock (the
 * other bits of the registers kept); -EINVAL beyond the table's 65,536 bits. */
int mbgw_table_write_bits(mbgw_table *t, int bit, int count, const uint8_t *packed);

/* Registers [first, first + count) stale (on) or current: a read (FC 1-4, FC 23's read
 * part) touching a stale register answers exception 0x0B, "gateway target failed to
 * respond" (a scenario's data too old to serve).  -EINVAL beyond the table. */
int mbgw_table_set_stale(mbgw_table *t, int first, int count, int on);

/* Counts the writes that changed a value in 0x0800-0x7FFF (the outputs and the free
 * zone): persistence saves when it has moved. */
uint64_t mbgw_table_persist_generation(mbgw_table *t);

/* by_function[fc * 3 + MBGW_TABLE_*] (256 * 3), by_exception[code] (16): since the last
 * reset.  A broadcast counts as such whatever it did. */
#define MBGW_TABLE_ANSWERED 0
#define MBGW_TABLE_EXCEPTION 1
#define MBGW_TABLE_BROADCAST 2
void mbgw_table_counts(mbgw_table *t, uint64_t *by_function, uint64_t *by_exception);
void mbgw_table_reset_counts(mbgw_table *t);

/* Watches: a change of a value in [first, first + count) sets the watch's flag and, if fd
 * is an eventfd (else -1), writes 1 to it once until the flag is taken (a write that
 * stores the same value changes nothing, but with first_writes a register's first write
 * since start does).  For scenarios sent on change and transparent mode's tx area.
 * mbgw_table_watch returns the watch's id, -EINVAL for a bad range, -ENOSPC when all are
 * in use.  mbgw_table_take_change returns the flag and clears it, and copies the range's
 * registers to out (if not NULL) under the same lock, so no change is lost between the
 * two. */
#define MBGW_TABLE_WATCHES 512
int mbgw_table_watch(mbgw_table *t, int first, int count, int fd, int first_writes);
void mbgw_table_unwatch(mbgw_table *t, int id);
int mbgw_table_take_change(mbgw_table *t, int id, uint16_t *out);

/* The raw line monitor (capture.c): while set, every byte read from or written to the
 * serial line is appended to buf as records: direction (1 byte), time (int64
 * CLOCK_MONOTONIC ns), length (uint16), the bytes, both numbers in the machine's order.
 * Bytes that do not fit are counted in dropped.  Set and drained by the line's thread
 * only, one per thread; NULL: off.  unset: off, if c is this thread's. */
#define MBGW_CAPTURE_RX 0
#define MBGW_CAPTURE_TX 1
#define MBGW_CAPTURE_HEAD 11
struct mbgw_capture {
    uint8_t *buf;
    size_t cap;
    size_t len;
    uint64_t dropped;
};
void mbgw_capture_set(struct mbgw_capture *c);
void mbgw_capture_unset(struct mbgw_capture *c);

/* modbus_send_raw_request (libmodbus appends the CRC), noted in the capture.  0, or -1
 * with errno set. */
int mbgw_send_rtu(struct _modbus *ctx, const uint8_t *adu, size_t len);
