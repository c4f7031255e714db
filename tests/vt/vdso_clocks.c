// Clock reads that go around libc's clock_gettime: glibc's own (timespec_get, ftime, which call
// the vDSO directly), the vDSO's functions called as a program that finds the vDSO itself
// does, and times(). Each must tell simulated time on virtual time as the kernel's clock does
// natively: 1.5 s after the start, across a sleep of 1.5 s.
#define _GNU_SOURCE
// ftime is deprecated, and still called.
#pragma GCC diagnostic ignored "-Wdeprecated-declarations"
#include <dlfcn.h>
#include <stdio.h>
#include <sys/time.h>
#include <sys/timeb.h>
#include <sys/times.h>
#include <time.h>
#include <unistd.h>

static double since(const struct timespec *start, const struct timespec *now) {
    return (double)(now->tv_sec - start->tv_sec) + (double)(now->tv_nsec - start->tv_nsec) / 1e9;
}

int main(void) {
    struct timespec start, slept = {1, 500000000}, now;
    clock_gettime(CLOCK_REALTIME, &start);
    clock_t ticks = times(NULL);
    nanosleep(&slept, NULL);

    timespec_get(&now, TIME_UTC);
    printf("timespec_get: %.2f s after the start\n", since(&start, &now));

    struct timeb fb;
    ftime(&fb);
    now.tv_sec = fb.time;
    now.tv_nsec = (long)fb.millitm * 1000000L;
    printf("ftime: %.2f s after the start\n", since(&start, &now));

    long tick = sysconf(_SC_CLK_TCK);
    printf("times: %.2f s after the start\n", (double)(times(NULL) - ticks) / (double)tick);
    struct tms cpu;
    printf("times with a buffer: %s\n", times(&cpu) != (clock_t)-1 ? "answered" : "failed");

    // The vDSO as a program that looks it up itself finds it (glibc's handle to it).
    void *vdso = dlopen("linux-vdso.so.1", RTLD_NOW | RTLD_NOLOAD);
    int (*vdso_clock_gettime)(clockid_t, struct timespec *) = vdso ? dlsym(vdso, "__vdso_clock_gettime") : NULL;
    int (*vdso_gettimeofday)(struct timeval *, void *) = vdso ? dlsym(vdso, "__vdso_gettimeofday") : NULL;
    time_t (*vdso_time)(time_t *) = vdso ? dlsym(vdso, "__vdso_time") : NULL;
    if (!vdso_clock_gettime || !vdso_gettimeofday || !vdso_time) {
        printf("the vDSO's clock functions: not found\n");
        return 1;
    }
    vdso_clock_gettime(CLOCK_REALTIME, &now);
    printf("the vDSO's clock_gettime: %.2f s after the start\n", since(&start, &now));
    struct timespec mono_start, mono_now;
    clock_gettime(CLOCK_MONOTONIC, &mono_start);
    vdso_clock_gettime(CLOCK_MONOTONIC, &mono_now);
    printf("its monotonic clock against libc's: %.2f s apart\n", since(&mono_start, &mono_now));
    struct timeval tv;
    struct timezone tz = {-1, -1};
    vdso_gettimeofday(&tv, &tz);
    now.tv_sec = tv.tv_sec;
    now.tv_nsec = tv.tv_usec * 1000L;
    printf("the vDSO's gettimeofday: %.2f s after the start, time zone filled: %s\n", since(&start, &now), tz.tz_minuteswest != -1 ? "yes" : "no");
    time_t seconds = vdso_time(NULL);
    clock_gettime(CLOCK_REALTIME, &now);
    printf("the vDSO's time: %s\n", seconds == now.tv_sec || seconds + 1 == now.tv_sec ? "the same second as clock_gettime" : "another second");
    // A clock the vDSO leaves to the kernel goes there still.
    struct timespec cpu_time = {-1, -1};
    int answer = vdso_clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cpu_time);
    printf("the vDSO's thread CPU clock: %d, %s\n", answer, cpu_time.tv_sec >= 0 && cpu_time.tv_nsec >= 0 ? "read" : "not read");
    printf("the vDSO's clock -1: %d\n", vdso_clock_gettime(-1, &now));
    return 0;
}
