/* A controller that writes 0xff over virtual time's shared block (found through CLIMBSIM_VT) and
 * aborts: for tests/virtual_time_limits.rs, whose run must fail saying so, every time. */
#include <fcntl.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>
#include <time.h>
int main(void) {
    struct timespec ts = {0, 100000000};
    nanosleep(&ts, NULL);
    const char *path = getenv("CLIMBSIM_VT");
    if (!path) return 2;
    int fd = open(path, O_RDWR);
    struct stat st;
    fstat(fd, &st);
    void *block = mmap(NULL, st.st_size, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
    memset(block, 0xff, st.st_size);
    abort();
}
