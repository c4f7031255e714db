/* A service's way to end: set up, then pause() until SIGTERM, whose handler sets a flag; then
 * the last report and exit 0. On virtual time the run's SIGTERM comes while the program waits
 * in pause at the scenario's end. */
#include <signal.h>
#include <stdio.h>
#include <unistd.h>

static volatile sig_atomic_t stopping;
static void on_term(int sig) { (void)sig; stopping = 1; }

int main(void) {
    signal(SIGTERM, on_term);
    puts("waiting for SIGTERM");
    fflush(stdout);
    while (!stopping)
        pause();
    puts("SIGTERM handled, final report written");
    return 0;
}
