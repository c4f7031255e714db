// Robust mutexes whose owner ends holding them: the next locker gets EOWNERDEAD, at the
// instant the owner ended, whether it already waited (the kernel hands the mutex on as the
// owner exits: climbsim's shim does it for waiters in its own queues) or locks later. A thread
// that ends holding one, and a process that dies holding a shared one.
#include <errno.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

static double now_ms(void) {
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return now.tv_sec * 1e3 + now.tv_nsec / 1e6;
}

static const char *answer(int rc) {
    return rc == EOWNERDEAD ? "EOWNERDEAD" : rc == 0 ? "0" : strerror(rc);
}

static void robust(pthread_mutex_t *mutex, int shared) {
    pthread_mutexattr_t attributes;
    pthread_mutexattr_init(&attributes);
    pthread_mutexattr_setrobust(&attributes, PTHREAD_MUTEX_ROBUST);
    pthread_mutexattr_setpshared(&attributes, shared ? PTHREAD_PROCESS_SHARED : PTHREAD_PROCESS_PRIVATE);
    pthread_mutex_init(mutex, &attributes);
}

static pthread_mutex_t mutex;

static void *take_and_end(void *unused) {
    (void)unused;
    pthread_mutex_lock(&mutex);
    return NULL;
}

static void *take_and_end_at_30_ms(void *unused) {
    (void)unused;
    pthread_mutex_lock(&mutex);
    usleep(30000);
    return NULL;
}

static void *take_shared_and_wait(void *shared) {
    pthread_mutex_lock(shared);
    pause();
    return NULL;
}

/* A child that takes the shared mutex and dies holding it at 30 ms, through _exit. */
static void lock_and_die_at_30_ms(pthread_mutex_t *shared) {
    pthread_mutex_lock(shared);
    usleep(30000);
    _exit(0);
}

/* A child whose second thread takes it, and which exits at 30 ms, through exit. */
static void lock_in_a_thread_and_exit_at_30_ms(pthread_mutex_t *shared) {
    pthread_t holder;
    pthread_create(&holder, NULL, take_shared_and_wait, shared);
    usleep(30000);
    exit(0);
}

/* The parent locks the shared robust mutex 10 ms after forking `child`, and says what it got. */
static void lock_while_a_child_dies(pthread_mutex_t *shared, void (*child)(pthread_mutex_t *), const char *owner) {
    fflush(stdout);
    double start = now_ms();
    pid_t pid = fork();
    if (pid == 0) {
        child(shared);
    }
    usleep(10000);
    int rc = pthread_mutex_lock(shared);
    printf("lock of a shared one %s: %s after %.3f ms\n", owner, answer(rc), now_ms() - start);
    waitpid(pid, NULL, 0);
}

int main(void) {
    robust(&mutex, 0);
    pthread_t thread;
    pthread_create(&thread, NULL, take_and_end, NULL);
    pthread_join(thread, NULL);
    int rc = pthread_mutex_lock(&mutex);
    printf("lock after its owner thread ended: %s\n", answer(rc));
    pthread_mutex_consistent(&mutex);
    pthread_mutex_unlock(&mutex);

    double start = now_ms();
    pthread_create(&thread, NULL, take_and_end_at_30_ms, NULL);
    usleep(10000);
    rc = pthread_mutex_lock(&mutex);
    printf("lock waiting for an owner thread that ends at 30 ms: %s after %.3f ms\n", answer(rc), now_ms() - start);
    pthread_mutex_consistent(&mutex);
    pthread_mutex_unlock(&mutex);
    pthread_join(thread, NULL);

    pthread_mutex_t *shared = mmap(NULL, sizeof *shared, PROT_READ | PROT_WRITE, MAP_SHARED | MAP_ANONYMOUS, -1, 0);
    robust(shared, 1);
    lock_while_a_child_dies(shared, lock_and_die_at_30_ms, "waiting for an owner process that dies at 30 ms");
    pthread_mutex_consistent(shared);
    pthread_mutex_unlock(shared);
    lock_while_a_child_dies(shared, lock_in_a_thread_and_exit_at_30_ms, "held by another thread of a process that exits at 30 ms");
    return 0;
}
