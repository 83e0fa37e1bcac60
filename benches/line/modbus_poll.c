/* The libmodbus side of `cargo bench --bench line`: polls a TRP-C29U's inputs (FC01, coils
 * 0x20-0x27, as rigscript reads them) through modbus_read_bits until SIGTERM, then prints
 * "POLLS ERRORS". With a gap above zero it sleeps that long before each request, keeping the
 * t3.5 of silence Modbus over Serial Line asks for; with 0 it polls back to back, as libmodbus
 * does by itself.
 *
 * usage: modbus_poll PORT BAUD GAP_US */
#include <errno.h>
#include <modbus.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static volatile sig_atomic_t stop;

static void on_term(int sig) {
    (void)sig;
    stop = 1;
}

int main(int argc, char **argv) {
    if (argc != 4) {
        fprintf(stderr, "usage: %s PORT BAUD GAP_US\n", argv[0]);
        return 2;
    }
    long baud = strtol(argv[2], NULL, 10);
    long gap_us = strtol(argv[3], NULL, 10);
    modbus_t *ctx = modbus_new_rtu(argv[1], (int)baud, 'N', 8, 1);
    if (ctx == NULL || modbus_set_slave(ctx, 1) == -1 || modbus_connect(ctx) == -1) {
        fprintf(stderr, "modbus_poll: cannot open %s: %s\n", argv[1], modbus_strerror(errno));
        return 1;
    }
    modbus_set_response_timeout(ctx, 0, 200000);
    struct sigaction sa = {0};
    sa.sa_handler = on_term;
    sigaction(SIGTERM, &sa, NULL);
    struct timespec gap = {gap_us / 1000000, (gap_us % 1000000) * 1000};
    uint8_t bits[8];
    long polls = 0, errors = 0;
    while (!stop) {
        if (gap_us > 0) {
            clock_nanosleep(CLOCK_MONOTONIC, 0, &gap, NULL);
        }
        if (modbus_read_bits(ctx, 0x20, 8, bits) == 8) {
            polls++;
        } else if (!stop) {
            errors++;
        }
    }
    printf("%ld %ld\n", polls, errors);
    modbus_close(ctx);
    modbus_free(ctx);
    return 0;
}
