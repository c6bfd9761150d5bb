/*
 * startup_cm4.c - minimal Cortex-M4F start-up for the ns2 test images (QEMU
 * netduinoplus2 / STM32F405): vector table, .data/.bss set-up, FPU enable
 * (CPACR CP10/CP11 full access), then main() and, in images built with
 * NS2_SEMIHOSTING (QEMU test images), semihosting I/O and exit.
 */
#include <stdint.h>

extern uint32_t _estack, _sidata, _sdata, _edata, _sbss, _ebss;
extern int main(void);
extern void initialise_monitor_handles(void);
void ns2_reset_handler(void);
void ns2_fault_handler(void);
void ns2_semihost_exit(int code);

#define CPACR (*(volatile uint32_t *)0xE000ED88u)

__attribute__((section(".isr_vector"), used)) static const uintptr_t vectors[16] = {
    (uintptr_t)&_estack,
    (uintptr_t)ns2_reset_handler,
    (uintptr_t)ns2_fault_handler, /* NMI */
    (uintptr_t)ns2_fault_handler, /* HardFault */
    (uintptr_t)ns2_fault_handler, /* MemManage */
    (uintptr_t)ns2_fault_handler, /* BusFault */
    (uintptr_t)ns2_fault_handler, /* UsageFault */
    0, 0, 0, 0,
    (uintptr_t)ns2_fault_handler, /* SVCall */
    0, 0,
    (uintptr_t)ns2_fault_handler, /* PendSV */
    (uintptr_t)ns2_fault_handler, /* SysTick */
};

void ns2_semihost_exit(int code)
{
#ifdef NS2_SEMIHOSTING
    /* SYS_EXIT (0x18) with ADP_Stopped_ApplicationExit; QEMU exits with the status
     * when the reason is ApplicationExit and the subcode is passed (extended form
     * is not needed: non-zero codes use RunTimeErrorUnknown). */
    register uint32_t r0 __asm__("r0") = 0x18u;
    register uint32_t r1 __asm__("r1") = code == 0 ? 0x20026u : 0x20024u;
    __asm__ volatile("bkpt 0xAB" : : "r"(r0), "r"(r1) : "memory");
#else
    (void)code; /* no debugger attached on a board: stop here */
#endif
    for (;;) {
    }
}

void ns2_fault_handler(void)
{
    ns2_semihost_exit(3);
}

void ns2_reset_handler(void)
{
    uint32_t *src = &_sidata;
    for (uint32_t *dst = &_sdata; dst < &_edata;) {
        *dst++ = *src++;
    }
    for (uint32_t *dst = &_sbss; dst < &_ebss;) {
        *dst++ = 0u;
    }
    CPACR |= (0xFu << 20);
    __asm__ volatile("dsb\n\tisb" ::: "memory");
#ifdef NS2_SEMIHOSTING
    initialise_monitor_handles();
#endif
    ns2_semihost_exit(main());
}

/* newlib's libc_init_array hooks; nothing to run */
void _init(void);
void _fini(void);
void _init(void) {}
void _fini(void) {}
