/* The benchmark's serial line: a simulated Modbus RTU slave and a direct RTU master, both on
 * a pty.  bench.py compiles this at run time (cc -O2) and drives it; it is not part of mbgw.
 *
 *   simline slave DEVICE|- BAUD [UNIT COUNT]
 *       Serve FC03/FC04 reads for unit 1 on DEVICE ("-": create a pty and print its name),
 *       and for UNIT its first COUNT reads only (a device that dies; never counted as bad).
 *       BAUD > 0: for each request, wait the time the request and the reply would take on
 *       the wire (10 bits a character, 8N1) from the request's arrival, then write the
 *       reply in one piece -- the write is the end of the reply on the line.  BAUD 0: answer
 *       at once.  For every request after the first it records the gap between the end of
 *       the previous reply and the request's arrival, how long writing that reply took, and
 *       the time since the previous request.  It runs SCHED_FIFO when allowed (a real slave
 *       is hardware of its own).  Commands on stdin: "r" resets the records, "d" dumps
 *       them, "q" quits.
 *   simline tcp
 *       A Modbus TCP server on 127.0.0.1 (port printed) that answers FC03 at once: the floor
 *       of a TCP round trip for the benchmark's client, with no gateway in the way.
 *   simline relay DEVICE
 *       The least a gateway can be: a Modbus TCP server on 127.0.0.1 (port printed) that
 *       puts each FC03 request of its one client on DEVICE as an RTU frame and sends back
 *       the 25-byte reply, in one thread, checking nothing.  What it adds over the direct
 *       master is what the TCP hop and the wake-ups cost on this host, whoever the gateway.
 *   simline master DEVICE T35_US SECONDS [PAUSE_US]
 *       A direct master: send FC03 (unit 1, 10 registers), read the 25-byte reply, wait
 *       T35_US (plus PAUSE_US, default 0) from the reply's last byte, send the next one; for
 *       SECONDS.  Prints the count, the elapsed time and every latency (request written ->
 *       reply's last byte).
 *
 * Waits sleep with clock_nanosleep (timer slack 1 ns) to just before their end and spin the
 * rest, so the simulated wire times are exact to a few microseconds.  The slave does not spin
 * while it waits for a request: pty data reaches the other side through a kworker, and on a
 * small machine a spinning reader starves that kworker for a whole scheduler slice.  So a
 * request's arrival is seen one wake-up late (tens of microseconds): the direct master's
 * gaps, which are t3.5 exactly on the master's side, show that floor. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sched.h>
#include <sys/ioctl.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#define CHAR_BITS 10            /* 8N1: start, 8 data, stop */
#define SPIN_FINAL_NS 80000     /* sleeps end this early and spin the rest */
#define MAX_RECORDS 2000000

static int64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

static void wait_until(int64_t t)
{
    int64_t sleep_to = t - SPIN_FINAL_NS;
    if (sleep_to > now_ns()) {
        struct timespec ts = { sleep_to / 1000000000, sleep_to % 1000000000 };
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR)
            ;
    }
    while (now_ns() < t)
        ;
}

static uint16_t crc16(const uint8_t *p, size_t n)
{
    uint16_t crc = 0xFFFF;
    while (n--) {
        crc ^= *p++;
        for (int i = 0; i < 8; i++)
            crc = (crc & 1) ? (crc >> 1) ^ 0xA001 : crc >> 1;
    }
    return crc;
}

static void add_crc(uint8_t *p, size_t n)
{
    uint16_t c = crc16(p, n);
    p[n] = c & 0xFF;
    p[n + 1] = c >> 8;
}

static void make_raw(int fd)
{
    struct termios t;
    if (tcgetattr(fd, &t) == 0) {
        cfmakeraw(&t);
        cfsetspeed(&t, B115200);
        tcsetattr(fd, TCSANOW, &t);
    }
}

static void die(const char *what)
{
    perror(what);
    exit(1);
}

/* ---------------------------------------------------------------- slave */

/* For each request after the first: the gap from the end of the previous reply's write()
 * to the request's arrival, and how long that write() took -- if the slave was held up in
 * it, the reply reached the line up to that much earlier and the real gap was that much
 * longer. */
static int64_t *gaps, *writes, *cycles;    /* cycles: from the previous request's arrival */
static size_t n_gaps;
static long n_tx, n_collisions, n_bad;
static int64_t reply_end;       /* when the previous reply was written; 0: none (or reset) */

static void dump(void)
{
    printf("STATS %ld %zu %ld %ld\nGAPS", n_tx, n_gaps, n_collisions, n_bad);
    for (size_t i = 0; i < n_gaps; i++)
        printf(" %lld,%lld,%lld", (long long)gaps[i], (long long)writes[i],
               (long long)cycles[i]);
    printf("\n");
    fflush(stdout);
}

/* Handle a command from stdin; returns 0 on quit or end of file. */
static int command(void)
{
    char buf[64];
    ssize_t n = read(0, buf, sizeof buf);
    if (n <= 0)
        return 0;
    for (ssize_t i = 0; i < n; i++) {
        switch (buf[i]) {
        case 'r':
            n_gaps = 0;
            n_tx = n_collisions = n_bad = 0;
            reply_end = 0;
            printf("OK\n");
            fflush(stdout);
            break;
        case 'd':
            dump();
            break;
        case 'q':
            return 0;
        }
    }
    return 1;
}

static int run_slave(const char *device, long baud, int dying_unit, long dying_left)
{
    int fd, keep = -1;
    const char *name = device;
    if (strcmp(device, "-") == 0) {
        fd = posix_openpt(O_RDWR | O_NOCTTY | O_NONBLOCK);
        if (fd < 0 || grantpt(fd) < 0 || unlockpt(fd) < 0)
            die("posix_openpt");
        name = ptsname(fd);
        /* Hold the pts open so the master side never sees a hang-up between clients. */
        keep = open(name, O_RDWR | O_NOCTTY);
        if (keep < 0)
            die(name);
        make_raw(keep);
    } else {
        fd = open(device, O_RDWR | O_NOCTTY | O_NONBLOCK);
        if (fd < 0)
            die(device);
        make_raw(fd);
    }
    gaps = malloc(sizeof *gaps * MAX_RECORDS);
    writes = malloc(sizeof *writes * MAX_RECORDS);
    cycles = malloc(sizeof *cycles * MAX_RECORDS);
    int64_t char_ns = baud > 0 ? (int64_t)CHAR_BITS * 1000000000 / baud : 0;
    /* A real slave is hardware of its own: run ahead of the gateway when we may, so it
     * never waits for a CPU (and the timestamps are not held up by a preemption). */
    struct sched_param sp = { .sched_priority = 10 };
    const char *policy = sched_setscheduler(0, SCHED_FIFO, &sp) == 0 ? "fifo" : "other";
    printf("READY %s %s\n", name, policy);
    fflush(stdout);

    uint8_t req[300], rsp[300];
    size_t have = 0;
    int64_t first_ns = 0;       /* arrival of the current request's first byte */
    int64_t prev_first_ns = 0;
    int64_t write_ns = 0;       /* how long writing it took */
    for (;;) {
        struct pollfd p[2] = { { fd, POLLIN, 0 }, { 0, POLLIN, 0 } };
        int rc = ppoll(p, 2, NULL, NULL);
        int64_t seen = now_ns();
        if (rc < 0) {
            if (errno == EINTR)
                continue;
            die("ppoll");
        }
        if (rc == 0)
            continue;
        if (p[1].revents) {
            if (!command())
                return 0;
        }
        if (p[0].revents & (POLLHUP | POLLERR)) {
            usleep(1000);       /* nobody holds the line open (only with a device path) */
            continue;
        }
        if (!(p[0].revents & POLLIN))
            continue;
        ssize_t n = read(fd, req + have, sizeof req - have);
        if (n <= 0)
            continue;
        if (have == 0)
            first_ns = seen;
        have += (size_t)n;
        if (have < 2)
            continue;
        size_t want = (req[1] == 3 || req[1] == 4) ? 8 : 0;
        int dying = dying_unit > 0 && req[0] == dying_unit && dying_left > 0;
        if (want == 0 || (req[0] != 1 && !dying)) {
            n_bad++;
            have = 0;
            continue;
        }
        if (have < want)
            continue;
        if (have > want || crc16(req, want) != 0) {
            n_bad++;
            have = 0;
            continue;
        }
        have = 0;
        if (dying)
            dying_left--;
        n_tx++;
        if (reply_end && n_gaps < MAX_RECORDS) {
            gaps[n_gaps] = first_ns - reply_end;
            writes[n_gaps] = write_ns;
            cycles[n_gaps++] = first_ns - prev_first_ns;
        }
        prev_first_ns = first_ns;
        unsigned qty = (req[4] << 8) | req[5];
        if (qty < 1 || qty > 125)
            qty = 1;
        size_t len = 0;
        rsp[len++] = req[0];
        rsp[len++] = req[1];
        rsp[len++] = (uint8_t)(2 * qty);
        for (unsigned i = 0; i < qty; i++) {
            rsp[len++] = (uint8_t)(i >> 8);
            rsp[len++] = (uint8_t)i;
        }
        add_crc(rsp, len);
        len += 2;
        if (char_ns)
            wait_until(first_ns + (int64_t)(want + len) * char_ns);
        int pending = 0;
        if (ioctl(fd, FIONREAD, &pending) == 0 && pending > 0)
            n_collisions++;     /* the master talked over our reply */
        int64_t before = now_ns();
        if (write(fd, rsp, len) != (ssize_t)len)
            die("write");
        reply_end = now_ns();
        write_ns = reply_end - before;
    }
}

/* ---------------------------------------------------------------- master */

static int read_reply(int fd, uint8_t *buf, size_t want, int64_t deadline, int64_t *end)
{
    size_t have = 0;
    while (have < want) {
        int64_t left = deadline - now_ns();
        if (left <= 0)
            return -1;
        struct timespec ts = { left / 1000000000, left % 1000000000 };
        struct pollfd p = { fd, POLLIN, 0 };
        int rc = ppoll(&p, 1, &ts, NULL);
        if (rc < 0 && errno != EINTR)
            die("ppoll");
        if (rc <= 0)
            continue;
        ssize_t n = read(fd, buf + have, want - have);
        if (n > 0) {
            have += (size_t)n;
            *end = now_ns();
        }
    }
    return 0;
}

static int run_master(const char *device, int64_t t35_ns, int64_t pause_ns, double seconds)
{
    int fd = open(device, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (fd < 0)
        die(device);
    make_raw(fd);
    tcflush(fd, TCIOFLUSH);
    uint8_t req[8] = { 1, 3, 0, 0, 0, 10 }, rsp[25];
    add_crc(req, 6);
    size_t cap = (size_t)(seconds * 20000) + 1000;
    int64_t *lat = malloc(sizeof *lat * cap);
    size_t n = 0;
    long timeouts = 0, bad = 0;
    int64_t start = now_ns(), stop = start + (int64_t)(seconds * 1e9), end = 0;
    while (now_ns() < stop && n < cap) {
        int64_t sent = now_ns();
        if (write(fd, req, sizeof req) != (ssize_t)sizeof req)
            die("write");
        if (read_reply(fd, rsp, sizeof rsp, sent + 1000000000LL, &end) < 0) {
            timeouts++;
            end = now_ns();
        } else if (crc16(rsp, sizeof rsp) != 0 || rsp[0] != 1 || rsp[1] != 3) {
            bad++;
        } else {
            lat[n++] = end - sent;
        }
        wait_until(end + t35_ns + pause_ns);
    }
    int64_t elapsed = now_ns() - start;
    printf("RESULT %zu %lld %ld %ld\nLAT", n, (long long)elapsed, timeouts, bad);
    for (size_t i = 0; i < n; i++)
        printf(" %lld", (long long)lat[i]);
    printf("\n");
    return 0;
}

/* ---------------------------------------------------------------- TCP floor */

/* A listener on a free loopback port, announced as "READY PORT" on stdout. */
static int listen_loopback(void)
{
    int ls = socket(AF_INET, SOCK_STREAM, 0), one = 1;
    struct sockaddr_in a = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
    socklen_t alen = sizeof a;
    setsockopt(ls, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (bind(ls, (struct sockaddr *)&a, sizeof a) < 0 || listen(ls, 8) < 0 ||
        getsockname(ls, (struct sockaddr *)&a, &alen) < 0)
        die("listen");
    printf("READY %d\n", ntohs(a.sin_port));
    fflush(stdout);
    return ls;
}

/* The next client of ls, with Nagle off: one request, one reply, no waiting. */
static int accept_nodelay(int ls)
{
    int s = accept(ls, NULL, NULL), one = 1;
    if (s < 0)
        die("accept");
    setsockopt(s, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    return s;
}

static int run_tcp(void)
{
    int ls = listen_loopback();
    for (;;) {
        int s = accept_nodelay(ls);
        uint8_t req[12], rsp[29];
        size_t have = 0;
        for (;;) {
            ssize_t n = read(s, req + have, sizeof req - have);
            if (n <= 0)
                break;
            have += (size_t)n;
            if (have < sizeof req)
                continue;
            have = 0;
            unsigned count = 2 * (((unsigned)req[10] << 8) | req[11]);
            if (count > sizeof rsp - 9)
                count = sizeof rsp - 9;
            memcpy(rsp, req, 4);                    /* transaction and protocol ids */
            rsp[4] = 0;
            rsp[5] = (uint8_t)(3 + count);
            rsp[6] = req[6];
            rsp[7] = req[7];
            rsp[8] = (uint8_t)count;
            memset(rsp + 9, 0, count);
            if (write(s, rsp, 9 + count) < 0)
                break;
        }
        close(s);
    }
    return 0;
}

/* ---------------------------------------------------------------- least gateway */

static int run_relay(const char *device)
{
    int fd = open(device, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (fd < 0)
        die(device);
    make_raw(fd);
    int ls = listen_loopback();
    for (;;) {
        int s = accept_nodelay(ls);
        uint8_t req[12], rtu[8], rsp[25], out[29];
        for (;;) {
            size_t have = 0;
            while (have < sizeof req) {
                ssize_t n = read(s, req + have, sizeof req - have);
                if (n <= 0)
                    goto closed;
                have += (size_t)n;
            }
            memcpy(rtu, req + 6, 6);                /* unit, function, address, count */
            add_crc(rtu, 6);
            if (write(fd, rtu, sizeof rtu) != (ssize_t)sizeof rtu)
                die("write");
            int64_t end;
            if (read_reply(fd, rsp, sizeof rsp, now_ns() + 1000000000LL, &end) < 0)
                continue;
            memcpy(out, req, 4);
            out[4] = 0;
            out[5] = sizeof rsp - 2;
            memcpy(out + 6, rsp, sizeof rsp - 2);
            if (write(s, out, 6 + sizeof rsp - 2) < 0)
                break;
        }
closed:
        close(s);
    }
    return 0;
}

int main(int argc, char **argv)
{
    prctl(PR_SET_TIMERSLACK, 1UL, 0, 0, 0);
    if ((argc == 4 || argc == 6) && strcmp(argv[1], "slave") == 0)
        return run_slave(argv[2], atol(argv[3]), argc == 6 ? atoi(argv[4]) : 0,
                         argc == 6 ? atol(argv[5]) : 0);
    if (argc == 2 && strcmp(argv[1], "tcp") == 0)
        return run_tcp();
    if (argc == 3 && strcmp(argv[1], "relay") == 0)
        return run_relay(argv[2]);
    if ((argc == 5 || argc == 6) && strcmp(argv[1], "master") == 0)
        return run_master(argv[2], atoll(argv[3]) * 1000,
                          argc == 6 ? atoll(argv[5]) * 1000 : 0, atof(argv[4]));
    fprintf(stderr, "usage: simline slave DEVICE|- BAUD\n"
                    "       simline tcp\n"
                    "       simline relay DEVICE\n"
                    "       simline master DEVICE T35_US SECONDS [PAUSE_US]\n");
    return 2;
}
