/*
 * hil_usart.c - serial hardware-in-the-loop image for the STM32F405: the ns2
 * library behind the framed protocol of ns2_hil.h on a USART (polled).
 *
 * USART1 (0x40011000) by default: QEMU netduinoplus2 connects it to its first
 * serial port (-serial pty).  On a Crazyflie 2.x the deck-connector UART1 is
 * USART3 (0x40004800): build with -DNS2_HIL_USART_BASE=0x40004800u and
 * -DNS2_HIL_BRR for the board's APB clock and the wanted baud rate.
 */
#include <stdint.h>

#include "ns2_hil.h"

#ifndef NS2_HIL_USART_BASE
#define NS2_HIL_USART_BASE 0x40011000u
#endif
#ifndef NS2_HIL_BRR
#define NS2_HIL_BRR 0x2D9u /* 115200 baud at 84 MHz APB2 */
#endif

#define USART_SR (*(volatile uint32_t *)(NS2_HIL_USART_BASE + 0x00u))
#define USART_DR (*(volatile uint32_t *)(NS2_HIL_USART_BASE + 0x04u))
#define USART_BRR (*(volatile uint32_t *)(NS2_HIL_USART_BASE + 0x08u))
#define USART_CR1 (*(volatile uint32_t *)(NS2_HIL_USART_BASE + 0x0Cu))
#define RCC_APB1ENR (*(volatile uint32_t *)0x40023840u)
#define RCC_APB2ENR (*(volatile uint32_t *)0x40023844u)
#define SR_RXNE (1u << 5)
#define SR_TXE (1u << 7)

static ns2_hil_t hil;

static void usart_write(const uint8_t *data, uint16_t n)
{
    for (uint16_t i = 0; i < n; ++i) {
        while (!(USART_SR & SR_TXE)) {
        }
        USART_DR = data[i];
    }
}

int main(void)
{
    RCC_APB2ENR |= (1u << 4) | (1u << 5); /* USART1, USART6 */
    RCC_APB1ENR |= (1u << 17) | (1u << 18); /* USART2, USART3 */
    USART_BRR = NS2_HIL_BRR;
    USART_CR1 = (1u << 13) | (1u << 3) | (1u << 2); /* UE, TE, RE */
    ns2_hil_init(&hil, usart_write);
    for (;;) {
        if (USART_SR & SR_RXNE) {
            ns2_hil_feed(&hil, (uint8_t)(USART_DR & 0xFFu));
        }
    }
}
