#include <string.h>
#include "semihost.h"

#define SYS_OPEN (0x01)
#define SYS_CLOSE (0x02)
#define SYS_WRITE (0x05)
#define SYS_READ (0x06)
#define SYS_SEEK (0x0a)
#define SYS_FLEN (0x0c)
#define SYS_REMOVE (0x0e)
#define SYS_RENAME (0x0f)
#define SYS_ERRNO (0x13)
#define SYS_GET_CMDLINE (0x15)
#define SYS_EXIT_EXTENDED (0x20)
#define ADP_STOPPED_APPLICATION_EXIT (0x20026)

static int sh_call(int op, const void *arg) {
    register int r0 __asm__ ("r0") = op;
    register const void *r1 __asm__ ("r1") = arg;
    __asm__ volatile ("bkpt 0xab" : "+r" (r0) : "r" (r1) : "memory");
    return r0;
}

int sh_open(const char *path, int mode) {
    uint32_t a[3] = {(uint32_t)path, (uint32_t)mode, strlen(path)};
    return sh_call(SYS_OPEN, a);
}

int sh_close(int fd) {
    uint32_t a[1] = {(uint32_t)fd};
    return sh_call(SYS_CLOSE, a);
}

int sh_write(int fd, const void *buf, size_t len) {
    uint32_t a[3] = {(uint32_t)fd, (uint32_t)buf, len};
    int left = sh_call(SYS_WRITE, a);  // the count NOT written
    return left < 0 || (size_t)left > len ? -1 : (int)(len - left);
}

int sh_read(int fd, void *buf, size_t len) {
    uint32_t a[3] = {(uint32_t)fd, (uint32_t)buf, len};
    int left = sh_call(SYS_READ, a);
    return left < 0 || (size_t)left > len ? -1 : (int)(len - left);
}

int sh_seek(int fd, size_t pos) {
    uint32_t a[2] = {(uint32_t)fd, pos};
    return sh_call(SYS_SEEK, a);
}

int sh_flen(int fd) {
    uint32_t a[1] = {(uint32_t)fd};
    return sh_call(SYS_FLEN, a);
}

int sh_remove(const char *path) {
    uint32_t a[2] = {(uint32_t)path, strlen(path)};
    return sh_call(SYS_REMOVE, a);
}

int sh_rename(const char *from, const char *to) {
    uint32_t a[4] = {(uint32_t)from, strlen(from), (uint32_t)to, strlen(to)};
    return sh_call(SYS_RENAME, a);
}

int sh_errno(void) {
    return sh_call(SYS_ERRNO, NULL);
}

int sh_cmdline(char *buf, size_t len) {
    uint32_t a[2] = {(uint32_t)buf, len};
    if (sh_call(SYS_GET_CMDLINE, a) != 0) {
        return -1;
    }
    return (int)a[1];
}

// ":tt" opened for append is the host's stderr (QEMU's semihosting console).
void sh_stderr(const char *buf, size_t len) {
    static int fd = -1;
    if (fd < 0) {
        fd = sh_open(":tt", 8);
        if (fd < 0) {
            return;
        }
    }
    sh_write(fd, buf, len);
}

void sh_exit(int status) {
    uint32_t a[2] = {ADP_STOPPED_APPLICATION_EXIT, (uint32_t)status};
    sh_call(SYS_EXIT_EXTENDED, a);
    for (;;) {
    }
}
