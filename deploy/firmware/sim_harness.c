/*
 * Runs the firmware in simavr (libsimavr), feeds bytes into its UART and prints every
 * change of the IR pin (PB1 / OC1A) and every byte the firmware sends back:
 *     pin <cycle> <level>
 *     uart <cycle> <byte>          (sent by the firmware)
 *     rx <cycle> <byte>            (fed to the firmware)
 * Usage: sim_harness firmware.elf CODE [CODE ...]   (codes in decimal or 0x hex;
 *        wait:MS runs MS milliseconds more without input)
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"

static avr_t *avr;

static void on_pin(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)param;
    printf("pin %llu %u\n", (unsigned long long)avr->cycle, value);
}

static void on_uart(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)param;
    printf("uart %llu %u\n", (unsigned long long)avr->cycle, value);
}

static int run_until(avr_cycle_count_t cycle) {
    while (avr->cycle < cycle) {
        int state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed) {
            return -1;
        }
    }
    return 0;
}

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: %s firmware.elf CODE...\n", argv[0]);
        return 2;
    }
    elf_firmware_t fw = {{0}};
    if (elf_read_firmware(argv[1], &fw)) {
        fprintf(stderr, "cannot read %s\n", argv[1]);
        return 2;
    }
    avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) {
        return 2;
    }
    avr_init(avr);
    avr_load_firmware(avr, &fw);
    avr->frequency = 16000000;
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~AVR_UART_FLAG_STDIO;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), IOPORT_IRQ_PIN1),
                            on_pin, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            on_uart, NULL);
    avr_irq_t *rx = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    printf("freq %u\n", avr->frequency);
    avr_cycle_count_t ms = avr->frequency / 1000;
    if (run_until(2 * ms)) {
        return 1;
    }
    for (int i = 2; i < argc; ++i) {
        if (strncmp(argv[i], "wait:", 5) == 0) {
            if (run_until(avr->cycle + strtoul(argv[i] + 5, NULL, 0) * ms)) {
                return 1;
            }
            continue;
        }
        uint32_t byte = (uint32_t)strtoul(argv[i], NULL, 0);
        printf("rx %llu %u\n", (unsigned long long)avr->cycle, byte);
        avr_raise_irq(rx, byte);
        if (run_until(avr->cycle + 60 * ms)) {
            return 1;
        }
    }
    return 0;
}
