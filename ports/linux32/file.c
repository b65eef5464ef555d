// Files on POSIX file descriptors: open() (a path or an inherited descriptor), the io.FileIO /
// io.TextIOWrapper types, and sys.stdin/stdout/stderr (fds 0/1/2) with their .buffer, as the unix
// port has them. Reads and writes go straight to read(2)/write(2): write(buf, n) and
// readinto(buf) allocate nothing, so the rig's serial port works under heap_lock.
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <string.h>
#include <unistd.h>

#include "py/builtin.h"
#include "py/mperrno.h"
#include "py/runtime.h"
#include "py/stream.h"
#include "fdfile.h"

static void fdfile_print(const mp_print_t *print, mp_obj_t self_in, mp_print_kind_t kind) {
    (void)kind;
    fdfile_t *self = MP_OBJ_TO_PTR(self_in);
    mp_printf(print, "<io.%s %d>", mp_obj_get_type_str(self_in), self->fd);
}

static void check_open(fdfile_t *self) {
    if (self->fd < 0) {
        mp_raise_ValueError(MP_ERROR_TEXT("I/O operation on closed file"));
    }
}

static mp_uint_t fdfile_read(mp_obj_t self_in, void *buf, mp_uint_t size, int *errcode) {
    fdfile_t *self = MP_OBJ_TO_PTR(self_in);
    check_open(self);
    for (;;) {
        ssize_t n = read(self->fd, buf, size);
        if (n >= 0) {
            return n;
        }
        if (errno != EINTR) {
            *errcode = errno;
            return MP_STREAM_ERROR;
        }
        mp_handle_pending(true);
    }
}

static mp_uint_t fdfile_write(mp_obj_t self_in, const void *buf, mp_uint_t size, int *errcode) {
    fdfile_t *self = MP_OBJ_TO_PTR(self_in);
    check_open(self);
    const char *p = buf;
    mp_uint_t left = size;
    while (left > 0) {
        ssize_t n = write(self->fd, p, left);
        if (n < 0) {
            if (errno == EINTR) {
                mp_handle_pending(true);
                continue;
            }
            if (left < size) {
                break;
            }
            *errcode = errno;
            return MP_STREAM_ERROR;
        }
        p += n;
        left -= n;
    }
    return size - left;
}

static mp_uint_t fdfile_ioctl(mp_obj_t self_in, mp_uint_t request, uintptr_t arg, int *errcode) {
    fdfile_t *self = MP_OBJ_TO_PTR(self_in);
    if (request != MP_STREAM_CLOSE) {
        check_open(self);
    }
    switch (request) {
        case MP_STREAM_FLUSH:
            return 0;
        case MP_STREAM_SEEK: {
            struct mp_stream_seek_t *s = (struct mp_stream_seek_t *)arg;
            off_t off = lseek(self->fd, s->offset, s->whence);
            if (off < 0) {
                *errcode = errno;
                return MP_STREAM_ERROR;
            }
            s->offset = off;
            return 0;
        }
        case MP_STREAM_CLOSE:
            if (self->fd > 2) {  // the std files stay open (they live in ROM)
                close(self->fd);
                self->fd = -1;
            }
            return 0;
        case MP_STREAM_GET_FILENO:
            return self->fd;
        case MP_STREAM_POLL: {
            struct pollfd p = {self->fd, 0, 0};
            if (arg & MP_STREAM_POLL_RD) {
                p.events |= POLLIN;
            }
            if (arg & MP_STREAM_POLL_WR) {
                p.events |= POLLOUT;
            }
            if (poll(&p, 1, 0) < 0) {
                *errcode = errno;
                return MP_STREAM_ERROR;
            }
            mp_uint_t ret = 0;
            if (p.revents & POLLIN) {
                ret |= MP_STREAM_POLL_RD;
            }
            if (p.revents & POLLOUT) {
                ret |= MP_STREAM_POLL_WR;
            }
            if (p.revents & POLLERR) {
                ret |= MP_STREAM_POLL_ERR;
            }
            if (p.revents & POLLHUP) {
                ret |= MP_STREAM_POLL_HUP;
            }
            return ret;
        }
        default:
            *errcode = MP_EINVAL;
            return MP_STREAM_ERROR;
    }
}

static mp_obj_t fdfile_fileno(mp_obj_t self_in) {
    fdfile_t *self = MP_OBJ_TO_PTR(self_in);
    check_open(self);
    return MP_OBJ_NEW_SMALL_INT(self->fd);
}
static MP_DEFINE_CONST_FUN_OBJ_1(fdfile_fileno_obj, fdfile_fileno);

static mp_obj_t fdfile___exit__(size_t n_args, const mp_obj_t *args) {
    (void)n_args;
    return mp_stream_close(args[0]);
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(fdfile___exit___obj, 4, 4, fdfile___exit__);

static const mp_rom_map_elem_t fdfile_locals_dict_table[] = {
    { MP_ROM_QSTR(MP_QSTR_fileno), MP_ROM_PTR(&fdfile_fileno_obj) },
    { MP_ROM_QSTR(MP_QSTR_read), MP_ROM_PTR(&mp_stream_read_obj) },
    { MP_ROM_QSTR(MP_QSTR_readinto), MP_ROM_PTR(&mp_stream_readinto_obj) },
    { MP_ROM_QSTR(MP_QSTR_readline), MP_ROM_PTR(&mp_stream_unbuffered_readline_obj) },
    { MP_ROM_QSTR(MP_QSTR_readlines), MP_ROM_PTR(&mp_stream_unbuffered_readlines_obj) },
    { MP_ROM_QSTR(MP_QSTR_write), MP_ROM_PTR(&mp_stream_write_obj) },
    { MP_ROM_QSTR(MP_QSTR_seek), MP_ROM_PTR(&mp_stream_seek_obj) },
    { MP_ROM_QSTR(MP_QSTR_tell), MP_ROM_PTR(&mp_stream_tell_obj) },
    { MP_ROM_QSTR(MP_QSTR_flush), MP_ROM_PTR(&mp_stream_flush_obj) },
    { MP_ROM_QSTR(MP_QSTR_close), MP_ROM_PTR(&mp_stream_close_obj) },
    { MP_ROM_QSTR(MP_QSTR___del__), MP_ROM_PTR(&mp_stream_close_obj) },
    { MP_ROM_QSTR(MP_QSTR___enter__), MP_ROM_PTR(&mp_identity_obj) },
    { MP_ROM_QSTR(MP_QSTR___exit__), MP_ROM_PTR(&fdfile___exit___obj) },
};
static MP_DEFINE_CONST_DICT(fdfile_locals_dict, fdfile_locals_dict_table);

const mp_stream_p_t fdfile_binary_stream_p = {
    .read = fdfile_read,
    .write = fdfile_write,
    .ioctl = fdfile_ioctl,
};

static const mp_stream_p_t textio_stream_p = {
    .read = fdfile_read,
    .write = fdfile_write,
    .ioctl = fdfile_ioctl,
    .is_text = true,
};

MP_DEFINE_CONST_OBJ_TYPE(
    mp_type_fdfile_fileio, MP_QSTR_FileIO, MP_TYPE_FLAG_ITER_IS_STREAM,
    print, fdfile_print,
    protocol, &fdfile_binary_stream_p,
    locals_dict, &fdfile_locals_dict);

const fdfile_t mp_sys_stdin_buffer_obj = {{&mp_type_fdfile_fileio}, 0};
const fdfile_t mp_sys_stdout_buffer_obj = {{&mp_type_fdfile_fileio}, 1};
const fdfile_t mp_sys_stderr_buffer_obj = {{&mp_type_fdfile_fileio}, 2};

// .buffer of the std text files: the binary file on the same descriptor
static void textio_attr(mp_obj_t self_in, qstr attr, mp_obj_t *dest) {
    fdfile_t *self = MP_OBJ_TO_PTR(self_in);
    if (dest[0] == MP_OBJ_NULL && attr == MP_QSTR_buffer && self->fd >= 0 && self->fd <= 2) {
        static const fdfile_t *const buffers[] = {
            &mp_sys_stdin_buffer_obj, &mp_sys_stdout_buffer_obj, &mp_sys_stderr_buffer_obj
        };
        dest[0] = MP_OBJ_FROM_PTR(buffers[self->fd]);
    } else {
        dest[1] = MP_OBJ_SENTINEL;  // look in the locals dict
    }
}

MP_DEFINE_CONST_OBJ_TYPE(
    mp_type_fdfile_textio, MP_QSTR_TextIOWrapper, MP_TYPE_FLAG_ITER_IS_STREAM,
    print, fdfile_print,
    protocol, &textio_stream_p,
    attr, textio_attr,
    locals_dict, &fdfile_locals_dict);

const fdfile_t mp_sys_stdin_obj = {{&mp_type_fdfile_textio}, 0};
const fdfile_t mp_sys_stdout_obj = {{&mp_type_fdfile_textio}, 1};
const fdfile_t mp_sys_stderr_obj = {{&mp_type_fdfile_textio}, 2};

mp_obj_t fdfile_new(int fd, bool binary) {
    fdfile_t *f = mp_obj_malloc_with_finaliser(fdfile_t, binary ? &mp_type_fdfile_fileio : &mp_type_fdfile_textio);
    f->fd = fd;
    return MP_OBJ_FROM_PTR(f);
}

// open(file, mode="r"): file is a path or an open descriptor (then owned by the new file object)
mp_obj_t mp_builtin_open(size_t n_args, const mp_obj_t *args, mp_map_t *kwargs) {
    static const mp_arg_t allowed[] = {
        { MP_QSTR_file, MP_ARG_OBJ | MP_ARG_REQUIRED, {.u_rom_obj = MP_ROM_NONE} },
        { MP_QSTR_mode, MP_ARG_OBJ, {.u_rom_obj = MP_ROM_QSTR(MP_QSTR_r)} },
        { MP_QSTR_buffering, MP_ARG_INT, {.u_int = -1} },
        { MP_QSTR_encoding, MP_ARG_OBJ, {.u_rom_obj = MP_ROM_NONE} },
    };
    mp_arg_val_t vals[MP_ARRAY_SIZE(allowed)];
    mp_arg_parse_all(n_args, args, kwargs, MP_ARRAY_SIZE(allowed), allowed, vals);
    const char *mode = mp_obj_str_get_str(vals[1].u_obj);
    int flags = 0;
    bool binary = false;
    for (const char *m = mode; *m; m++) {
        switch (*m) {
            case 'r':
                flags = O_RDONLY;
                break;
            case 'w':
                flags = O_WRONLY | O_CREAT | O_TRUNC;
                break;
            case 'a':
                flags = O_WRONLY | O_CREAT | O_APPEND;
                break;
            case 'x':
                flags = O_WRONLY | O_CREAT | O_EXCL;
                break;
            case '+':
                flags = (flags & ~(O_RDONLY | O_WRONLY)) | O_RDWR;
                break;
            case 'b':
                binary = true;
                break;
            case 't':
                binary = false;
                break;
            default:
                mp_raise_ValueError(MP_ERROR_TEXT("invalid mode"));
        }
    }
    mp_obj_t file = vals[0].u_obj;
    if (mp_obj_is_small_int(file)) {
        return fdfile_new(MP_OBJ_SMALL_INT_VALUE(file), binary);
    }
    const char *path = mp_obj_str_get_str(file);
    int fd;
    while ((fd = open(path, flags | O_CLOEXEC, 0644)) < 0 && errno == EINTR) {
        mp_handle_pending(true);
    }
    if (fd < 0) {
        mp_raise_OSError_with_filename(errno, path);
    }
    return fdfile_new(fd, binary);
}
MP_DEFINE_CONST_FUN_OBJ_KW(mp_builtin_open_obj, 1, mp_builtin_open);
