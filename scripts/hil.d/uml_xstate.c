/*
 * LD_PRELOAD shim for Debian bookworm's user-mode Linux (6.1) on hosts whose XSAVE area is larger
 * than the one the UML kernel was built for (AVX-512, AMX: 2.7 to 11 KiB instead of 832 bytes).
 *
 * The UML kernel saves and restores each guest thread's FPU state with
 * ptrace(PTRACE_GETREGSET / PTRACE_SETREGSET, NT_X86_XSTATE) on a buffer of 832 bytes (legacy
 * area, XSAVE header, AVX upper halves). The host kernel accepts a short GETREGSET, but refuses a
 * SETREGSET whose size is not the task's whole XSAVE size with EFAULT, and UML then kills the
 * guest's first process ("userspace - ptrace set fp regs failed, errno = 14", kernel panic).
 *
 * This shim completes the buffer: every GETREGSET of NT_X86_XSTATE is made with the host's full
 * size, the first part goes to the caller and the whole state is kept, keyed by the caller's
 * buffer address (UML passes each guest thread's own save area, so the key is the thread); a
 * SETREGSET writes the kept state with the caller's part laid over it. The components beyond the
 * caller's part (AVX-512, PKRU, ...) are therefore carried per guest thread, as a host kernel
 * would. A buffer never read before (a new thread) gets those components in their initial state:
 * its XSAVE header keeps only the features that lie inside the caller's part.
 *
 * Everything else goes to the C library's ptrace unchanged. Build:
 *   gcc -O2 -shared -fPIC -o uml_xstate.so uml_xstate.c -ldl
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <elf.h>
#include <errno.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ptrace.h>
#include <sys/types.h>
#include <sys/uio.h>

#ifndef NT_X86_XSTATE
#define NT_X86_XSTATE 0x202
#endif
#define XSAVE_HEADER_OFFSET 512
#define PROBE_SIZE (64 * 1024)

typedef long (*ptrace_fn)(int, pid_t, void *, void *);

struct slot {
    void *key;
    unsigned char *state; /* full_size bytes */
};

static ptrace_fn real_ptrace;
static size_t full_size; /* the host's XSAVE size for a traced task; 0 until known */
static struct slot *slots;
static size_t nslots, capslots;
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;

static long call_real(int req, pid_t pid, void *addr, void *data)
{
    if (!real_ptrace)
        real_ptrace = (ptrace_fn)dlsym(RTLD_NEXT, "ptrace");
    return real_ptrace(req, pid, addr, data);
}

static struct slot *find_slot(void *key, int create)
{
    for (size_t i = 0; i < nslots; i++)
        if (slots[i].key == key)
            return &slots[i];
    if (!create)
        return NULL;
    if (nslots == capslots) {
        size_t cap = capslots ? 2 * capslots : 256;
        struct slot *grown = realloc(slots, cap * sizeof *slots);
        if (!grown)
            return NULL;
        slots = grown;
        capslots = cap;
    }
    unsigned char *state = calloc(1, full_size);
    if (!state)
        return NULL;
    slots[nslots].key = key;
    slots[nslots].state = state;
    return &slots[nslots++];
}

/* The host's size, learnt from a GETREGSET with a large buffer (the kernel shortens iov_len). */
static int learn_size(pid_t pid)
{
    if (full_size)
        return 0;
    unsigned char *probe = malloc(PROBE_SIZE);
    if (!probe)
        return -1;
    struct iovec iov = {probe, PROBE_SIZE};
    long rc = call_real(PTRACE_GETREGSET, pid, (void *)(uintptr_t)NT_X86_XSTATE, &iov);
    if (rc == 0)
        full_size = iov.iov_len;
    free(probe);
    return rc == 0 ? 0 : -1;
}

static long getregset(pid_t pid, struct iovec *user)
{
    if (learn_size(pid) != 0 || user->iov_len >= full_size)
        return call_real(PTRACE_GETREGSET, pid, (void *)(uintptr_t)NT_X86_XSTATE, user);
    struct slot *s = find_slot(user->iov_base, 1);
    if (!s) {
        errno = ENOMEM;
        return -1;
    }
    struct iovec iov = {s->state, full_size};
    long rc = call_real(PTRACE_GETREGSET, pid, (void *)(uintptr_t)NT_X86_XSTATE, &iov);
    if (rc == 0)
        memcpy(user->iov_base, s->state, user->iov_len);
    return rc;
}

static long setregset(pid_t pid, struct iovec *user)
{
    if (learn_size(pid) != 0 || user->iov_len >= full_size)
        return call_real(PTRACE_SETREGSET, pid, (void *)(uintptr_t)NT_X86_XSTATE, user);
    struct slot *s = find_slot(user->iov_base, 0);
    int fresh = s == NULL;
    if (fresh && !(s = find_slot(user->iov_base, 1))) {
        errno = ENOMEM;
        return -1;
    }
    memcpy(s->state, user->iov_base, user->iov_len);
    if (fresh && user->iov_len >= XSAVE_HEADER_OFFSET + 8) {
        /* Only x87, SSE and (if the caller's part holds it) AVX are given; the rest start in
           their initial state. */
        uint64_t xfeatures;
        memcpy(&xfeatures, s->state + XSAVE_HEADER_OFFSET, sizeof xfeatures);
        xfeatures &= user->iov_len >= 832 ? 0x7 : 0x3;
        memcpy(s->state + XSAVE_HEADER_OFFSET, &xfeatures, sizeof xfeatures);
    }
    struct iovec iov = {s->state, full_size};
    return call_real(PTRACE_SETREGSET, pid, (void *)(uintptr_t)NT_X86_XSTATE, &iov);
}

long ptrace(enum __ptrace_request request, ...)
{
    int req = (int)request;
    va_list ap;
    va_start(ap, request);
    pid_t pid = va_arg(ap, pid_t);
    void *addr = va_arg(ap, void *);
    void *data = va_arg(ap, void *);
    va_end(ap);
    if ((req == PTRACE_GETREGSET || req == PTRACE_SETREGSET)
        && (uintptr_t)addr == NT_X86_XSTATE && data) {
        pthread_mutex_lock(&lock);
        long rc = req == PTRACE_GETREGSET ? getregset(pid, data) : setregset(pid, data);
        int saved = errno;
        pthread_mutex_unlock(&lock);
        errno = saved;
        return rc;
    }
    return call_real(req, pid, addr, data);
}
