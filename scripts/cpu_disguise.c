/* LD_PRELOAD shim: this process's CPUID instructions report another x86-64 CPU.

Built and used by scripts/cpu_disguise.py (read its docstring). With CPUID_DISGUISE set to a comma list of
  amd         vendor AuthenticAMD, family 19h (Zen 3), AMD's cache leaves (Zen 3's caches), no Intel leaf 4
  intel       on an AMD CPU: vendor GenuineIntel, family 6 model 6Ah (Ice Lake server), Intel's cache leaves
              2 and 4 (Zen 3's sizes), no AMD-only extended leaves; on an Intel CPU nothing changes
  noavx512    no AVX-512 (nor AMX, AVX-VNNI, AVX512-BF16/FP16) in leaf 7
  smallcache  Intel's cache leaf 4 reports Zen 3's sizes (L1d 32 KiB, L2 512 KiB, L3 32 MiB)
it turns on the kernel's CPUID faulting for the process (arch_prctl ARCH_SET_CPUID, kept across fork and
threads, reset by execve, where LD_PRELOAD loads this again): every CPUID then traps into a SIGSEGV
handler that runs the real instruction, edits its answer and steps over it. A later sigaction(SIGSEGV) of
the program is kept aside and called for real faults. Exit status 3 at start when the CPU or kernel has
no CPUID faulting (the cpuid_fault flag of /proc/cpuinfo). */
#define _GNU_SOURCE
#include <asm/prctl.h>
#include <cpuid.h>
#include <dlfcn.h>
#include <signal.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/syscall.h>
#include <ucontext.h>
#include <unistd.h>

static int amd, intel, no_avx512, small_cache, active;  /* active: our SIGSEGV handler is installed */

static long set_cpuid(int enabled) { return syscall(SYS_arch_prctl, ARCH_SET_CPUID, (unsigned long)enabled); }

static void amd_cache(uint32_t sub, uint32_t *a, uint32_t *b, uint32_t *c, uint32_t *d) {
    /* Zen 3: L1d 32 KiB 8-way, L1i 32 KiB 8-way, L2 512 KiB 8-way, L3 32 MiB 16-way; 64-byte lines. */
    static const uint32_t type[] = {1, 2, 3, 3}, level[] = {1, 1, 2, 3}, ways[] = {8, 8, 8, 16};
    static const uint32_t size[] = {32u << 10, 32u << 10, 512u << 10, 32u << 20}, share[] = {1, 1, 1, 15};
    if (sub > 3) { *a = *b = *c = *d = 0; return; }
    *a = type[sub] | (level[sub] << 5) | (1u << 8) | (share[sub] << 14);
    *b = 63u | (ways[sub] - 1) << 22;
    *c = size[sub] / (ways[sub] * 64) - 1;
    *d = sub == 3 ? 1u : 0u;
}

/* What an Intel CPU answers where an AMD one answers otherwise. AMD's leaf 4 is empty and its extended leaves
   carry the caches and AMD-only features; Intel reports caches through leaves 2 and 4. Only called on AMD. */
static void intel_on_amd(uint32_t leaf, uint32_t sub, uint32_t *a, uint32_t *b, uint32_t *c, uint32_t *d) {
    if (leaf == 0) { memcpy(b, "Genu", 4); memcpy(d, "ineI", 4); memcpy(c, "ntel", 4); }
    if (leaf == 1) *a = 0x000606A6; /* family 6, model 6Ah, stepping 6 (Ice Lake server) */
    if (leaf == 2) { *a = 0x00FEFF01; *b = 0xF0; *c = *d = 0; } /* descriptor FFh: read leaf 4 */
    if (leaf == 4) amd_cache(sub, a, b, c, d);
    if (leaf == 0x80000000) *a = 0x80000008;
    if (leaf == 0x80000001) *c &= ~((1u << 2) | (1u << 6) | (1u << 11) | (1u << 16) | (1u << 22) | (1u << 23)); /* SVM, SSE4A, XOP, FMA4, TOPOEXT, PERFCTR */
    if (leaf == 0x80000005) *a = *b = *c = *d = 0;
    if (leaf == 0x80000006) { *a = *b = *d = 0; *c = (512u << 16) | (6u << 12) | 64u; }
    if (leaf > 0x80000008 && leaf < 0x90000000) *a = *b = *c = *d = 0;
}

static void disguise(uint32_t leaf, uint32_t sub, uint32_t *a, uint32_t *b, uint32_t *c, uint32_t *d) {
    if (no_avx512 && leaf == 7 && sub == 0) {
        *b &= ~((1u << 16) | (1u << 17) | (1u << 21) | (1u << 26) | (1u << 27) | (1u << 28) | (1u << 30) | (1u << 31));
        *c &= ~((1u << 1) | (1u << 6) | (1u << 11) | (1u << 12) | (1u << 14));
        *d &= ~((1u << 2) | (1u << 3) | (1u << 8) | (1u << 22) | (1u << 23) | (1u << 24) | (1u << 25));
    }
    if (no_avx512 && leaf == 7 && sub == 1) *a &= ~((1u << 4) | (1u << 5));
    if (small_cache && leaf == 4) { uint32_t keep = *a & 0xfc000000u; amd_cache(sub, a, b, c, d); if (*a) *a |= keep; }
    if (intel) intel_on_amd(leaf, sub, a, b, c, d);
    if (!amd) return;
    if (leaf == 0) { memcpy(b, "Auth", 4); memcpy(d, "enti", 4); memcpy(c, "cAMD", 4); }
    if (leaf == 1) *a = 0x00A00F11; /* family 19h (Zen 3), model 01h */
    if (leaf == 4) *a = *b = *c = *d = 0; /* Intel's cache leaf: AMD reports none */
    if (leaf == 0x80000000) *a = 0x80000021;
    if (leaf == 0x80000001) *c |= 1u << 22; /* TopologyExtensions: leaf 8000001Dh is valid */
    if (leaf == 0x80000005) { *a = *b = 0; *c = (32u << 24) | (8u << 16) | (1u << 8) | 64u; *d = *c; }
    if (leaf == 0x80000006) { *a = *b = 0; *c = (512u << 16) | (6u << 12) | (1u << 8) | 64u; *d = (64u << 18) | (8u << 12) | (1u << 8) | 64u; }
    /* Intel answers leaves above its own last (80000008h) with its last basic leaf: report them empty. */
    if (leaf > 0x80000008 && leaf <= 0x80000021) *a = *b = *c = *d = 0;
    if (leaf == 0x8000001D) amd_cache(sub, a, b, c, d);
}

static struct sigaction chained;  /* the program's own SIGSEGV handler, called for real faults */

static void on_segv(int sig, siginfo_t *info, void *context) {
    ucontext_t *uc = context;
    greg_t *g = uc->uc_mcontext.gregs;
    const unsigned char *ip = (const unsigned char *)g[REG_RIP];
    if (ip[0] == 0x0f && ip[1] == 0xa2) {
        uint32_t leaf = (uint32_t)g[REG_RAX], sub = (uint32_t)g[REG_RCX], a, b, c, d;
        set_cpuid(1);
        __cpuid_count(leaf, sub, a, b, c, d);
        set_cpuid(0);
        disguise(leaf, sub, &a, &b, &c, &d);
        g[REG_RAX] = a; g[REG_RBX] = b; g[REG_RCX] = c; g[REG_RDX] = d;
        g[REG_RIP] += 2;
        return;
    }
    if (chained.sa_flags & SA_SIGINFO && chained.sa_sigaction) { chained.sa_sigaction(sig, info, context); return; }
    if (chained.sa_handler != SIG_DFL && chained.sa_handler != SIG_IGN && chained.sa_handler) { chained.sa_handler(sig); return; }
    signal(SIGSEGV, SIG_DFL);  /* returning re-executes the faulting instruction: now a normal crash */
}

/* Keep our handler installed: a later sigaction(SIGSEGV) (Python's faulthandler, ...) is chained instead. */
int sigaction(int sig, const struct sigaction *act, struct sigaction *old) {
    static int (*real)(int, const struct sigaction *, struct sigaction *);
    if (!real) real = (int (*)(int, const struct sigaction *, struct sigaction *))dlsym(RTLD_NEXT, "sigaction");
    if (sig == SIGSEGV && active) {
        if (old) *old = chained;
        if (act) chained = *act;
        return 0;
    }
    return real(sig, act, old);
}

__attribute__((constructor)) static void start(void) {
    const char *what = getenv("CPUID_DISGUISE");
    if (!what) return;
    amd = strstr(what, "amd") != NULL;
    uint32_t a, b, c, d;
    __cpuid(0, a, b, c, d);  /* the host's vendor, before faulting is on: "intel" rewrites an AMD CPU only */
    intel = strstr(what, "intel") != NULL && memcmp(&b, "Auth", 4) == 0;
    no_avx512 = strstr(what, "noavx512") != NULL;
    small_cache = strstr(what, "smallcache") != NULL;
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_sigaction = on_segv;
    sa.sa_flags = SA_SIGINFO | SA_NODEFER;
    sigemptyset(&sa.sa_mask);
    int (*real)(int, const struct sigaction *, struct sigaction *) =
        (int (*)(int, const struct sigaction *, struct sigaction *))dlsym(RTLD_NEXT, "sigaction");
    real(SIGSEGV, &sa, NULL);
    active = 1;
    if (set_cpuid(0) != 0) { const char m[] = "cpuid_disguise: CPUID faulting not available\n"; write(2, m, sizeof m - 1); _exit(3); }
}
