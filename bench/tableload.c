/* The table row's load generator, and the fastest Modbus TCP server this host can have.
 * bench/table.py compiles this at run time (cc -O2) and drives it; it is not part of mbgw.
 *
 *   tableload client PORT CLIENTS REGISTERS UNIT WARMUP_S SECONDS [LATENCY_FILE]
 *       CLIENTS connections to 127.0.0.1:PORT, each a closed loop of FC03 reads of REGISTERS
 *       registers from address 0 of UNIT: its next request goes the moment its reply is in.
 *       One thread, epoll: a request costs the generator a send, a recv and its share of an
 *       epoll_wait.  Every reply is checked (transaction id, protocol, unit, function, byte
 *       count, length); an exception or a wrong reply is an error.  Prints "START" when the
 *       measured window opens and "END" when it closes (the caller samples the server's CPU
 *       time then), then
 *           RESULT count errors window_ns p50_ns p99_ns max_ns user_us sys_us least most
 *       latency: request sent -> whole reply read; user/sys: the generator's own CPU time in
 *       the window; least/most: the fewest and most replies one client had in it.  With
 *       LATENCY_FILE, every latency of the window goes there too, sorted, as native uint64 ns
 *       (for pooling runs).
 *   tableload raw PORT
 *       A Modbus TCP server on 127.0.0.1:PORT, epoll, one thread, that answers every FC03 with
 *       zeros and checks nothing: the ceiling for this generator on this host.  Prints
 *       "READY PORT".
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#define MAX_CLIENTS 256
#define BUF 600

static uint64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

static void die(const char *what)
{
    perror(what);
    exit(1);
}

static void nodelay(int fd)
{
    int one = 1;
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
}

struct conn {
    int fd;
    uint16_t tid;
    int waiting;
    uint64_t sent;
    uint64_t count;
    int have;
    uint8_t buf[BUF];
};

static struct conn conns[MAX_CLIENTS];
static int registers, unit;

static void send_request(struct conn *c)
{
    uint8_t req[12];
    c->tid++;
    req[0] = c->tid >> 8; req[1] = c->tid & 0xff;
    req[2] = 0; req[3] = 0; req[4] = 0; req[5] = 6;
    req[6] = unit; req[7] = 3;
    req[8] = 0; req[9] = 0;
    req[10] = registers >> 8; req[11] = registers & 0xff;
    c->sent = now_ns();
    if (send(c->fd, req, sizeof req, MSG_NOSIGNAL) != (ssize_t)sizeof req)
        die("send");
    c->waiting = 1;
}

/* 1: a whole good reply; 0: not whole yet; -1: a whole reply that is wrong. */
static int take_reply(struct conn *c)
{
    ssize_t n = recv(c->fd, c->buf + c->have, BUF - c->have, 0);
    if (n == 0) {
        fprintf(stderr, "tableload: the server closed a connection\n");
        exit(1);
    }
    if (n < 0) {
        if (errno == EAGAIN || errno == EINTR)
            return 0;
        die("recv");
    }
    c->have += (int)n;
    if (c->have < 6)
        return 0;
    int size = 6 + (c->buf[4] << 8 | c->buf[5]);
    if (size > BUF) {
        fprintf(stderr, "tableload: a reply of %d bytes\n", size);
        exit(1);
    }
    if (c->have < size)
        return 0;
    const uint8_t *f = c->buf;
    int good = size == 9 + 2 * registers && (f[0] << 8 | f[1]) == c->tid && f[2] == 0 &&
               f[3] == 0 && f[6] == unit && f[7] == 3 && f[8] == 2 * registers;
    c->have -= size;
    memmove(c->buf, c->buf + size, (size_t)c->have);
    c->waiting = 0;
    return good ? 1 : -1;
}

static int cmp_u64(const void *a, const void *b)
{
    uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return x < y ? -1 : x > y;
}

static uint64_t pct(const uint64_t *v, size_t n, double q)
{
    if (n == 0)
        return 0;
    size_t rank = (size_t)(q / 100.0 * (double)n + 0.999999);
    if (rank < 1)
        rank = 1;
    if (rank > n)
        rank = n;
    return v[rank - 1];
}

static uint64_t cpu_us(const struct timeval *tv)
{
    return (uint64_t)tv->tv_sec * 1000000u + (uint64_t)tv->tv_usec;
}

static int connect_to(int port)
{
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port)};
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0)
        die("socket");
    if (connect(fd, (struct sockaddr *)&a, sizeof a) < 0)
        die("connect");
    nodelay(fd);
    return fd;
}

static void write_latencies(const char *path, const uint64_t *lat, size_t count)
{
    FILE *f = fopen(path, "wb");
    if (f == NULL || fwrite(lat, sizeof *lat, count, f) != count || fclose(f) != 0)
        die(path);
}

static int run_client(int port, int n, double warmup_s, double seconds, const char *lat_path)
{
    int ep = epoll_create1(EPOLL_CLOEXEC);
    if (ep < 0)
        die("epoll_create1");
    for (int i = 0; i < n; i++) {
        conns[i].fd = connect_to(port);
        struct epoll_event ev = {.events = EPOLLIN, .data.ptr = &conns[i]};
        if (epoll_ctl(ep, EPOLL_CTL_ADD, conns[i].fd, &ev) < 0)
            die("epoll_ctl");
    }
    size_t cap = 1 << 20, count = 0;
    uint64_t *lat = malloc(cap * sizeof *lat);
    if (lat == NULL)
        die("malloc");
    uint64_t errors = 0;
    uint64_t begin = now_ns();
    uint64_t t0 = begin + (uint64_t)(warmup_s * 1e9), t1 = 0, drain_end = 0;
    int measuring = 0, draining = 0;
    struct rusage ru0, ru1;
    for (int i = 0; i < n; i++)
        send_request(&conns[i]);
    struct epoll_event events[MAX_CLIENTS];
    for (;;) {
        int ready = epoll_wait(ep, events, MAX_CLIENTS, 100);
        if (ready < 0) {
            if (errno == EINTR)
                continue;
            die("epoll_wait");
        }
        uint64_t now = now_ns();
        if (!measuring && !draining && now >= t0) {
            getrusage(RUSAGE_SELF, &ru0);
            printf("START\n");
            fflush(stdout);
            t0 = now_ns();
            t1 = t0 + (uint64_t)(seconds * 1e9);
            measuring = 1;
            for (int i = 0; i < n; i++)
                conns[i].count = 0;
        }
        if (measuring && now >= t1) {
            getrusage(RUSAGE_SELF, &ru1);
            printf("END\n");
            fflush(stdout);
            measuring = 0;
            draining = 1;
            drain_end = now + 2000000000u;
        }
        for (int e = 0; e < ready; e++) {
            struct conn *c = events[e].data.ptr;
            int ok = take_reply(c);
            if (ok == 0)
                continue;
            uint64_t done = now_ns();
            if (measuring && done <= t1) {
                if (ok > 0) {
                    if (count == cap) {
                        cap *= 2;
                        lat = realloc(lat, cap * sizeof *lat);
                        if (lat == NULL)
                            die("realloc");
                    }
                    lat[count++] = done - c->sent;
                    c->count++;
                } else {
                    errors++;
                }
            }
            if (!draining)
                send_request(c);
        }
        if (draining) {
            int waiting = 0;
            for (int i = 0; i < n; i++)
                waiting += conns[i].waiting;
            if (waiting == 0 || now_ns() >= drain_end) {
                errors += (uint64_t)waiting;
                break;
            }
        }
    }
    qsort(lat, count, sizeof *lat, cmp_u64);
    if (lat_path != NULL)
        write_latencies(lat_path, lat, count);
    uint64_t least = UINT64_MAX, most = 0;
    for (int i = 0; i < n; i++) {
        if (conns[i].count < least)
            least = conns[i].count;
        if (conns[i].count > most)
            most = conns[i].count;
    }
    printf("RESULT %zu %llu %llu %llu %llu %llu %llu %llu %llu %llu\n", count,
           (unsigned long long)errors, (unsigned long long)(t1 - t0),
           (unsigned long long)pct(lat, count, 50), (unsigned long long)pct(lat, count, 99),
           (unsigned long long)pct(lat, count, 100),
           (unsigned long long)(cpu_us(&ru1.ru_utime) - cpu_us(&ru0.ru_utime)),
           (unsigned long long)(cpu_us(&ru1.ru_stime) - cpu_us(&ru0.ru_stime)),
           (unsigned long long)least, (unsigned long long)most);
    return 0;
}

/* ------------------------------------------------------------------ the raw server */

static int run_raw(int port)
{
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port)};
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    int lfd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0), one = 1;
    setsockopt(lfd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (bind(lfd, (struct sockaddr *)&a, sizeof a) < 0 || listen(lfd, 128) < 0)
        die("bind/listen");
    int ep = epoll_create1(EPOLL_CLOEXEC);
    struct epoll_event lev = {.events = EPOLLIN, .data.ptr = NULL};
    epoll_ctl(ep, EPOLL_CTL_ADD, lfd, &lev);
    printf("READY %d\n", port);
    fflush(stdout);
    struct epoll_event events[64];
    uint8_t rsp[9 + 2 * 125];
    memset(rsp, 0, sizeof rsp);
    for (;;) {
        int ready = epoll_wait(ep, events, 64, -1);
        if (ready < 0) {
            if (errno == EINTR)
                continue;
            die("epoll_wait");
        }
        for (int e = 0; e < ready; e++) {
            struct conn *c = events[e].data.ptr;
            if (c == NULL) {
                int fd = accept4(lfd, NULL, NULL, SOCK_CLOEXEC);
                if (fd < 0)
                    continue;
                nodelay(fd);
                c = calloc(1, sizeof *c);
                c->fd = fd;
                struct epoll_event ev = {.events = EPOLLIN, .data.ptr = c};
                epoll_ctl(ep, EPOLL_CTL_ADD, fd, &ev);
                continue;
            }
            ssize_t n = recv(c->fd, c->buf + c->have, BUF - c->have, 0);
            if (n <= 0) {
                close(c->fd);
                free(c);
                continue;
            }
            c->have += (int)n;
            while (c->have >= 12) {
                int size = 6 + (c->buf[4] << 8 | c->buf[5]);
                if (c->have < size)
                    break;
                int quantity = c->buf[10] << 8 | c->buf[11];
                if (quantity > 125)
                    quantity = 125;
                memcpy(rsp, c->buf, 4);
                rsp[4] = 0;
                rsp[5] = (uint8_t)(3 + 2 * quantity);
                rsp[6] = c->buf[6];
                rsp[7] = 3;
                rsp[8] = (uint8_t)(2 * quantity);
                send(c->fd, rsp, (size_t)(9 + 2 * quantity), MSG_NOSIGNAL);
                c->have -= size;
                memmove(c->buf, c->buf + size, (size_t)c->have);
            }
        }
    }
    return 0;
}

int main(int argc, char **argv)
{
    if ((argc == 8 || argc == 9) && strcmp(argv[1], "client") == 0) {
        int n = atoi(argv[3]);
        registers = atoi(argv[4]);
        unit = atoi(argv[5]);
        if (n < 1 || n > MAX_CLIENTS || registers < 1 || registers > 125)
            return 2;
        return run_client(atoi(argv[2]), n, atof(argv[6]), atof(argv[7]),
                          argc == 9 ? argv[8] : NULL);
    }
    if (argc == 3 && strcmp(argv[1], "raw") == 0)
        return run_raw(atoi(argv[2]));
    fprintf(stderr, "usage: tableload client PORT CLIENTS REGISTERS UNIT WARMUP_S SECONDS "
                    "[LATENCY_FILE]\n"
                    "       tableload raw PORT\n");
    return 2;
}
