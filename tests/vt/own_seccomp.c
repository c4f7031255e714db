/* A program with a seccomp filter of its own (as sandboxes install them: Chrome's, systemd's,
 * a controller that locks itself down): its filter traps getppid with its own data (7), and
 * its own SIGSYS handler answers the call. Under virtual time the shim's filter is there too;
 * each trap goes to the handler whose filter asked for it, and the program's sleeps are still
 * followed. Natively: the handler answers 4242, with data 7, for call 110. */
#define _GNU_SOURCE
#include <linux/filter.h>
#include <linux/seccomp.h>
#include <signal.h>
#include <stddef.h>
#include <stdio.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/syscall.h>
#include <time.h>
#include <ucontext.h>
#include <unistd.h>

static volatile int trapped_data = -1, trapped_call = -1;

static void on_sigsys(int sig, siginfo_t *info, void *context) {
    (void)sig;
    ucontext_t *registers = context;
    trapped_data = info->si_errno;
    trapped_call = info->si_syscall;
    registers->uc_mcontext.gregs[REG_RAX] = 4242;
}

static double now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

int main(void) {
    struct sigaction action;
    memset(&action, 0, sizeof action);
    action.sa_sigaction = on_sigsys;
    action.sa_flags = SA_SIGINFO;
    if (sigaction(SIGSYS, &action, NULL) != 0) {
        perror("sigaction");
        return 1;
    }
    struct sock_filter code[] = {
        BPF_STMT(BPF_LD | BPF_W | BPF_ABS, offsetof(struct seccomp_data, nr)),
        BPF_JUMP(BPF_JMP | BPF_JEQ | BPF_K, SYS_getppid, 0, 1),
        BPF_STMT(BPF_RET | BPF_K, SECCOMP_RET_TRAP | 7),
        BPF_STMT(BPF_RET | BPF_K, SECCOMP_RET_ALLOW),
    };
    struct sock_fprog program = {sizeof code / sizeof code[0], code};
    if (prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0 || prctl(PR_SET_SECCOMP, SECCOMP_MODE_FILTER, &program) != 0) {
        perror("seccomp");
        return 1;
    }
    long answer = syscall(SYS_getppid);
    printf("getppid under the program's own filter: %ld, trapped with data %d for call %d\n", answer, trapped_data, trapped_call);
    fflush(stdout);
    double start = now_ms();
    struct timespec pause = {0, 10000000};
    nanosleep(&pause, NULL);
    printf("then a 10 ms sleep: %s\n", now_ms() - start >= 10.0 ? "slept" : "too short");
    return 0;
}
