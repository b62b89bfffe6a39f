/* libmodbus's own Modbus TCP server, the reference of the table row: built by bench/table.py
 * at run time (cc -O2 ... -lmodbus); it is not part of mbgw.
 *
 *   libmodbus_server PORT
 *       Listens on 127.0.0.1:PORT and serves a modbus_mapping_new of 65536 holding and 65536
 *       input registers (all zero) to any number of clients: one thread, a select() loop over
 *       the listening socket and the clients, modbus_receive + modbus_reply for each request
 *       -- the way libmodbus's own examples serve several clients.  Prints "READY PORT".
 */
#define _GNU_SOURCE
#include <errno.h>
#include <modbus.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: libmodbus_server PORT\n");
        return 2;
    }
    int port = atoi(argv[1]);
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", port);
    modbus_mapping_t *map = modbus_mapping_new(0, 0, 65536, 65536);
    if (ctx == NULL || map == NULL) {
        fprintf(stderr, "libmodbus_server: %s\n", modbus_strerror(errno));
        return 1;
    }
    int server = modbus_tcp_listen(ctx, 128);
    if (server < 0) {
        fprintf(stderr, "libmodbus_server: listen: %s\n", modbus_strerror(errno));
        return 1;
    }
    printf("READY %d\n", port);
    fflush(stdout);

    uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
    fd_set clients;
    FD_ZERO(&clients);
    FD_SET(server, &clients);
    int fdmax = server;
    for (;;) {
        fd_set ready = clients;
        if (select(fdmax + 1, &ready, NULL, NULL, NULL) < 0) {
            if (errno == EINTR)
                continue;
            perror("select");
            return 1;
        }
        for (int fd = 0; fd <= fdmax; fd++) {
            if (!FD_ISSET(fd, &ready))
                continue;
            if (fd == server) {
                int client = accept(server, NULL, NULL);
                if (client < 0)
                    continue;
                int one = 1;
                setsockopt(client, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
                FD_SET(client, &clients);
                if (client > fdmax)
                    fdmax = client;
                continue;
            }
            modbus_set_socket(ctx, fd);
            int rc = modbus_receive(ctx, query);
            if (rc > 0) {
                modbus_reply(ctx, query, rc, map);
            } else if (rc < 0) {
                close(fd);
                FD_CLR(fd, &clients);
            }
        }
    }
}
