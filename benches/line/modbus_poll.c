/* The libmodbus side of `cargo bench --bench line`: polls a TRP-C29U's inputs (FC01, coils
 * 0x20-0x27, as rigscript reads them) through modbus_read_bits until SIGTERM, then prints
 * "POLLS ERRORS". With a gap above zero it sleeps that long before each request, keeping the
 * t3.5 of silence Modbus over Serial Line asks for; with 0 it polls back to back, as libmodbus
 * does by itself.
 *
 * With a LATENCY_US of 0 or more it asks Linux (PM QoS, /dev/cpu_dma_latency) to keep CPUs able
 * to wake that fast for as long as it runs, as `rigscript run --wake-latency auto` does; -1
 * asks nothing.
 *
 * usage: modbus_poll PORT BAUD GAP_US LATENCY_US */
#include <errno.h>
#include <fcntl.h>
#include <modbus.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

static volatile sig_atomic_t stop;

static void on_term(int sig) {
    (void)sig;
    stop = 1;
}

int main(int argc, char **argv) {
    if (argc != 5) {
        fprintf(stderr, "usage: %s PORT BAUD GAP_US LATENCY_US\n", argv[0]);
        return 2;
    }
    long baud = strtol(argv[2], NULL, 10);
    long gap_us = strtol(argv[3], NULL, 10);
    int32_t latency_us = (int32_t)strtol(argv[4], NULL, 10);
    /* Kept open to the end: the kernel drops the request when the file is closed. */
    if (latency_us >= 0) {
        int qos = open("/dev/cpu_dma_latency", O_WRONLY);
        if (qos == -1 || write(qos, &latency_us, sizeof latency_us) != sizeof latency_us) {
            fprintf(stderr, "modbus_poll: cannot hold a wake latency: %s\n", strerror(errno));
            return 1;
        }
    }
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
