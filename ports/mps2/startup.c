// Reset and vector table of the mps2-an385 (Cortex-M3): copy .data, clear .bss, 1 kHz SysTick, main().
#include <stdint.h>

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
int main(void);
void Reset_Handler(void) __attribute__((noreturn));
void SysTick_Handler(void);
void UART0RX_Handler(void);
void UART1RX_Handler(void);

static void Default_Handler(void) {
    for (;;) {
    }
}

void HardFault_Handler(void) {
    extern void mps2_fatal(const char *msg);
    mps2_fatal("HardFault\n");
}

#define SYST_CSR (*(volatile uint32_t *)0xe000e010)
#define SYST_RVR (*(volatile uint32_t *)0xe000e014)
#define SYST_CVR (*(volatile uint32_t *)0xe000e018)
#define MPS2_SYSCLK (25000000)

void Reset_Handler(void) {
    uint32_t *src = &_sidata;
    for (uint32_t *dst = &_sdata; dst < &_edata;) {
        *dst++ = *src++;
    }
    for (uint32_t *dst = &_sbss; dst < &_ebss;) {
        *dst++ = 0;
    }
    SYST_RVR = MPS2_SYSCLK / 1000 - 1;
    SYST_CVR = 0;
    SYST_CSR = 7;  // processor clock, interrupt, enable
    main();
    for (;;) {
    }
}

typedef void (*vector_t)(void);
__attribute__((section(".isr_vector"), used)) const vector_t vectors[16 + 32] = {
    (vector_t)&_estack,
    Reset_Handler,
    Default_Handler,    // NMI
    HardFault_Handler,
    HardFault_Handler,  // MemManage
    HardFault_Handler,  // BusFault
    HardFault_Handler,  // UsageFault
    0, 0, 0, 0,
    Default_Handler,    // SVC
    Default_Handler,    // DebugMon
    0,
    Default_Handler,    // PendSV
    SysTick_Handler,
    [16 + 0] = UART0RX_Handler,
    [16 + 2] = UART1RX_Handler,
};
