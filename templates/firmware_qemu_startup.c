/* Minimal Cortex-M4F start-up for QEMU mps2-an386 (the firmware folder's run_qemu.sh): copies .data,
   zeroes .bss, enables the FPU, runs main and exits through semihosting. */
#include <stdint.h>
extern int main(void);
extern uint32_t _estack, _sidata, _sdata, _edata, _sbss, _ebss;
void reset_handler(void);
static void semihost(uint32_t op, const void* arg) {
    register uint32_t r0 __asm__("r0") = op;
    register const void* r1 __asm__("r1") = arg;
    __asm__ volatile("bkpt 0xab" : "+r"(r0) : "r"(r1) : "memory");
}
void semihost_write0(const char* s) { semihost(0x04u, s); }
static void fault(void) { semihost(0x18u, (const void*)0x20023u); for (;;) {} }
__attribute__((section(".vectors"), used)) static const void* const vectors[16] = {
    &_estack, (const void*)reset_handler, (const void*)fault, (const void*)fault,
    (const void*)fault, (const void*)fault, (const void*)fault};
void reset_handler(void) {
    uint32_t *src = &_sidata, *dst = &_sdata;
    while (dst < &_edata) *dst++ = *src++;
    for (dst = &_sbss; dst < &_ebss;) *dst++ = 0;
    *(volatile uint32_t*)0xE000ED88u |= 0xFu << 20; /* CPACR: enable CP10, CP11 (the FPU) */
    __asm__ volatile("dsb\n isb");
    main();
    semihost(0x18u, (const void*)0x20026u); /* SYS_EXIT, ADP_Stopped_ApplicationExit */
    for (;;) {}
}
