/*
 * Robosapien V1 IR transmitter for an ATmega328P (Arduino Uno) at 16 MHz.
 *
 * Host protocol (services/ir_transmitter, serial backend): 115200 baud 8N1; the host sends
 * one raw byte per command, the Robosapien code itself (0x80-0xFF; e.g. 0x86 walk forward,
 * 0x8E stop). Each valid code is sent as one IR frame and echoed back when done; 0x00 is a
 * heartbeat; anything else below 0x80 is answered with '?' and ignored. When it is ready
 * (after a reset: an Arduino resets when the port opens), it announces itself with the line
 * "RSIR1\n"; the host sends nothing before it has read that.
 *
 * IR frame (as light; implementation notes, section 1): T = 1/1200 s ~ 833 us; a start mark
 * of 8T; then 8 bits, most significant first, each a space (T for 0, 4T for 1) followed by a
 * mark of T. A mark is the 39.2 kHz carrier on OC1A (PB1, Arduino pin 9): Timer 1 in CTC
 * mode toggles the pin at 2 x 39.2 kHz (OCR1A = 203: 39.216 kHz). See README.md for wiring.
 *
 * Watchdog: the host sends a heartbeat byte 0x00 every 150 ms (no IR, no reply). After a
 * motion command, if no byte at all arrives for WATCHDOG_MS (400 ms), the firmware sends STOP
 * by itself and reports '!'. A crashed host or a pulled USB cable cannot leave the robot
 * walking for more than half a second.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <stdint.h>
#include <util/delay.h>

#ifdef SIMAVR
#include <avr/avr_mcu_section.h> /* simavr: with -I/usr/include/simavr */
AVR_MCU(F_CPU, "atmega328p");
AVR_MCU_VCD_FILE("robosapien_ir.vcd", 1000);
const struct avr_mmcu_vcd_trace_t _mytrace[] _MMCU_ = {
    {AVR_MCU_VCD_SYMBOL("IR_OC1A"), .mask = (1 << PB1), .what = (void *)&PORTB},
};
#endif

#define BAUD 115200UL
#define T_US 833.0
#define CARRIER_HZ 39200UL
#define RX_SIZE 16
#define CODE_STOP 0x8E
#define CODE_HEARTBEAT 0x00
#define HELLO "RSIR1\n" /* services/ir_transmitter/protocol.py FIRMWARE_HELLO */
#ifndef WATCHDOG_MS
#define WATCHDOG_MS 400u
#endif

static volatile uint16_t ms_ticks; /* Timer 2 overflows every 1.024 ms */

ISR(TIMER2_OVF_vect) { ms_ticks++; }

static uint16_t now_ms(void) {
    uint16_t t;
    cli();
    t = ms_ticks;
    sei();
    return t;
}

static void clock_init(void) {
    TCCR2A = 0;
    TCCR2B = _BV(CS22); /* clk / 64: 250 kHz, overflow every 256 counts = 1.024 ms */
    TIMSK2 = _BV(TOIE2);
}

static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint8_t rx_head, rx_tail;

ISR(USART_RX_vect) {
    uint8_t b = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1) % RX_SIZE);
    if (next != rx_tail) { /* drop the byte if the buffer is full */
        rx_buf[rx_head] = b;
        rx_head = next;
    }
}

static void uart_init(void) {
    UCSR0A = _BV(U2X0);
    UBRR0 = (uint16_t)(F_CPU / 8 / BAUD - 1); /* 16: 115200 baud within 2.1% */
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
}

static int uart_available(void) { return rx_head != rx_tail; }

static uint8_t uart_read(void) {
    while (!uart_available()) {
    }
    uint8_t b = rx_buf[rx_tail];
    rx_tail = (uint8_t)((rx_tail + 1) % RX_SIZE);
    return b;
}

static void uart_write(uint8_t b) {
    while (!(UCSR0A & _BV(UDRE0))) {
    }
    UDR0 = b;
}

static inline void mark(void) { /* carrier on: OC1A toggles on every compare match */
    TCNT1 = 0;
    TCCR1A = _BV(COM1A0);
}

static inline void space(void) {
    /* carrier off: OC1A is cleared now (forced compare) and stays cleared on every match */
    TCCR1A = _BV(COM1A1);
    TCCR1C = _BV(FOC1A);
}

static void carrier_init(void) {
    PORTB &= (uint8_t)~_BV(PB1);
    DDRB |= _BV(PB1);
    TCCR1B = _BV(WGM12) | _BV(CS10); /* CTC on OCR1A, no prescaler */
    OCR1A = (uint16_t)(F_CPU / (2 * CARRIER_HZ) - 1);
    space();
}

static void send_frame(uint8_t code) {
    mark();
    _delay_us(8 * T_US);
    for (int8_t bit = 7; bit >= 0; --bit) {
        space();
        if (code & (uint8_t)(1u << bit)) {
            _delay_us(4 * T_US);
        } else {
            _delay_us(T_US);
        }
        mark();
        _delay_us(T_US);
    }
    space();
}

int main(void) {
    uart_init();
    carrier_init();
    clock_init();
    sei();
    for (const char *p = HELLO; *p; ++p) {
        uart_write((uint8_t)*p); /* ready: the host may send now */
    }
    uint8_t moving = 0;
    uint16_t last_rx = now_ms();
    for (;;) {
        if (!uart_available()) {
            if (moving && (uint16_t)(now_ms() - last_rx) > WATCHDOG_MS) {
                send_frame(CODE_STOP); /* the host went quiet: stop the robot */
                moving = 0;
                uart_write('!');
            }
            continue;
        }
        uint8_t code = uart_read();
        last_rx = now_ms();
        if (code == CODE_HEARTBEAT) {
            continue;
        }
        if (code < 0x80) {
            uart_write('?');
            continue;
        }
        send_frame(code);
        _delay_ms(10); /* a gap between frames */
        moving = code != CODE_STOP;
        uart_write(code);
    }
}
