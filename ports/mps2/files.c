// Files for the board: the ROM table first (frozen .mpy, bytecode runs in place from flash),
// then the host's files through semihosting (the board's "flash" is QEMU's working directory,
// so tables written by the firmware survive a power cut as on a real filesystem).
// Provides import stat, the .mpy/.py readers, open() and the os module.
#include <string.h>
#include "py/runtime.h"
#include "py/stream.h"
#include "py/reader.h"
#include "py/lexer.h"
#include "py/builtin.h"
#include "py/mperrno.h"
#include "semihost.h"
#include "romfs.h"

static const mps2_rom_file_t *rom_find(const char *path) {
    if (path[0] == '/') {
        path++;
    }
    for (size_t i = 0; i < mps2_rom_count; i++) {
        if (strcmp(mps2_rom_files[i].path, path) == 0) {
            return &mps2_rom_files[i];
        }
    }
    return NULL;
}

static bool rom_is_dir(const char *path) {
    if (path[0] == '/') {
        path++;
    }
    size_t n = strlen(path);
    for (size_t i = 0; i < mps2_rom_count; i++) {
        const char *p = mps2_rom_files[i].path;
        if (strncmp(p, path, n) == 0 && p[n] == '/') {
            return true;
        }
    }
    return false;
}

// Size of a host file or directory (opening a directory read-only works on a POSIX host), -1 if none.
static int host_size(const char *path) {
    int fd = sh_open(path, SH_OPEN_R);
    if (fd < 0) {
        return -1;
    }
    int n = sh_flen(fd);
    sh_close(fd);
    return n < 0 ? 0 : n;
}

mp_import_stat_t mp_import_stat(const char *path) {
    if (rom_find(path) != NULL) {
        return MP_IMPORT_STAT_FILE;
    }
    if (rom_is_dir(path)) {
        return MP_IMPORT_STAT_DIR;
    }
    // host files: a directory holds "." (a package dir on the host), a file does not
    size_t n = strlen(path);
    if (n + 3 > MICROPY_ALLOC_PATH_MAX) {
        return MP_IMPORT_STAT_NO_EXIST;
    }
    if (host_size(path) < 0) {
        return MP_IMPORT_STAT_NO_EXIST;
    }
    char buf[MICROPY_ALLOC_PATH_MAX];
    memcpy(buf, path, n);
    memcpy(buf + n, "/.", 3);
    return host_size(buf) >= 0 ? MP_IMPORT_STAT_DIR : MP_IMPORT_STAT_FILE;
}

// ---- readers -------------------------------------------------------------------------------

typedef struct {
    int fd;
    uint16_t len, pos;
    uint8_t buf[128];
} host_reader_t;

static mp_uint_t host_reader_readbyte(void *data) {
    host_reader_t *r = data;
    if (r->pos >= r->len) {
        int n = sh_read(r->fd, r->buf, sizeof(r->buf));
        if (n <= 0) {
            return MP_READER_EOF;
        }
        r->len = n;
        r->pos = 0;
    }
    return r->buf[r->pos++];
}

static void host_reader_close(void *data) {
    host_reader_t *r = data;
    sh_close(r->fd);
    m_del_obj(host_reader_t, r);
}

void mp_reader_new_file(mp_reader_t *reader, qstr filename) {
    const char *path = qstr_str(filename);
    const mps2_rom_file_t *f = rom_find(path);
    if (f != NULL) {
        mp_reader_new_mem(reader, f->data, f->len, MP_READER_IS_ROM);
        return;
    }
    int fd = sh_open(path, SH_OPEN_R);
    if (fd < 0) {
        mp_raise_OSError(MP_ENOENT);
    }
    host_reader_t *r = m_new_obj(host_reader_t);
    r->fd = fd;
    r->len = r->pos = 0;
    reader->data = r;
    reader->readbyte = host_reader_readbyte;
    reader->close = host_reader_close;
}

mp_lexer_t *mp_lexer_new_from_file(qstr filename) {
    mp_reader_t reader;
    mp_reader_new_file(&reader, filename);
    return mp_lexer_new(filename, reader);
}

// ---- open(): host files, binary or text ----------------------------------------------------

typedef struct {
    mp_obj_base_t base;
    int fd;
} host_file_obj_t;

static mp_uint_t host_file_read(mp_obj_t self_in, void *buf, mp_uint_t size, int *errcode) {
    host_file_obj_t *self = MP_OBJ_TO_PTR(self_in);
    if (self->fd < 0) {
        *errcode = MP_EBADF;
        return MP_STREAM_ERROR;
    }
    int n = sh_read(self->fd, buf, size);
    if (n < 0) {
        *errcode = MP_EIO;
        return MP_STREAM_ERROR;
    }
    return n;
}

static mp_uint_t host_file_write(mp_obj_t self_in, const void *buf, mp_uint_t size, int *errcode) {
    host_file_obj_t *self = MP_OBJ_TO_PTR(self_in);
    if (self->fd < 0) {
        *errcode = MP_EBADF;
        return MP_STREAM_ERROR;
    }
    int n = sh_write(self->fd, buf, size);
    if (n < 0) {
        *errcode = MP_EIO;
        return MP_STREAM_ERROR;
    }
    return n;
}

static mp_uint_t host_file_ioctl(mp_obj_t self_in, mp_uint_t request, uintptr_t arg, int *errcode) {
    host_file_obj_t *self = MP_OBJ_TO_PTR(self_in);
    if (request == MP_STREAM_CLOSE) {
        if (self->fd >= 0) {
            sh_close(self->fd);
            self->fd = -1;
        }
        return 0;
    }
    if (request == MP_STREAM_FLUSH) {
        return 0;  // semihosting writes reach the host file at once
    }
    if (request == MP_STREAM_SEEK) {
        struct mp_stream_seek_t *s = (struct mp_stream_seek_t *)arg;
        if (s->whence == MP_SEEK_END) {
            s->offset += sh_flen(self->fd);
        } else if (s->whence == MP_SEEK_CUR) {
            *errcode = MP_EINVAL;  // semihosting has no tell
            return MP_STREAM_ERROR;
        }
        sh_seek(self->fd, s->offset);
        return 0;
    }
    *errcode = MP_EINVAL;
    return MP_STREAM_ERROR;
}

static mp_obj_t host_file___exit__(size_t n_args, const mp_obj_t *args) {
    return mp_stream_close(args[0]);
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(host_file___exit___obj, 4, 4, host_file___exit__);

static const mp_rom_map_elem_t host_file_locals_dict_table[] = {
    { MP_ROM_QSTR(MP_QSTR_read), MP_ROM_PTR(&mp_stream_read_obj) },
    { MP_ROM_QSTR(MP_QSTR_readinto), MP_ROM_PTR(&mp_stream_readinto_obj) },
    // one host read(): what a pipe holds now, at least a byte (the HIL rig's request channel)
    { MP_ROM_QSTR(MP_QSTR_readinto1), MP_ROM_PTR(&mp_stream_readinto1_obj) },
    { MP_ROM_QSTR(MP_QSTR_readline), MP_ROM_PTR(&mp_stream_unbuffered_readline_obj) },
    { MP_ROM_QSTR(MP_QSTR_write), MP_ROM_PTR(&mp_stream_write_obj) },
    { MP_ROM_QSTR(MP_QSTR_seek), MP_ROM_PTR(&mp_stream_seek_obj) },
    { MP_ROM_QSTR(MP_QSTR_flush), MP_ROM_PTR(&mp_stream_flush_obj) },
    { MP_ROM_QSTR(MP_QSTR_close), MP_ROM_PTR(&mp_stream_close_obj) },
    { MP_ROM_QSTR(MP_QSTR___enter__), MP_ROM_PTR(&mp_identity_obj) },
    { MP_ROM_QSTR(MP_QSTR___exit__), MP_ROM_PTR(&host_file___exit___obj) },
};
static MP_DEFINE_CONST_DICT(host_file_locals_dict, host_file_locals_dict_table);

static const mp_stream_p_t host_file_stream_p = {
    .read = host_file_read,
    .write = host_file_write,
    .ioctl = host_file_ioctl,
    .is_text = false,
};

static const mp_stream_p_t host_textfile_stream_p = {
    .read = host_file_read,
    .write = host_file_write,
    .ioctl = host_file_ioctl,
    .is_text = true,
};

MP_DEFINE_CONST_OBJ_TYPE(host_file_type, MP_QSTR_FileIO, MP_TYPE_FLAG_ITER_IS_STREAM,
    protocol, &host_file_stream_p, locals_dict, &host_file_locals_dict);
MP_DEFINE_CONST_OBJ_TYPE(host_textfile_type, MP_QSTR_TextIOWrapper, MP_TYPE_FLAG_ITER_IS_STREAM,
    protocol, &host_textfile_stream_p, locals_dict, &host_file_locals_dict);

static mp_obj_t mps2_open(size_t n_args, const mp_obj_t *args, mp_map_t *kwargs) {
    const char *path = mp_obj_str_get_str(args[0]);
    const char *mode = n_args > 1 ? mp_obj_str_get_str(args[1]) : "r";
    mp_map_elem_t *m = mp_map_lookup(kwargs, MP_OBJ_NEW_QSTR(MP_QSTR_mode), MP_MAP_LOOKUP);
    if (m != NULL) {
        mode = mp_obj_str_get_str(m->value);
    }
    bool plus = strchr(mode, '+') != NULL;
    bool text = strchr(mode, 'b') == NULL;
    int sh_mode;
    switch (mode[0]) {
        case 'r':
            sh_mode = plus ? SH_OPEN_RW : SH_OPEN_R;
            break;
        case 'w':
            sh_mode = plus ? SH_OPEN_WR : SH_OPEN_W;
            break;
        case 'a':
            sh_mode = plus ? SH_OPEN_AR : SH_OPEN_A;
            break;
        default:
            mp_raise_ValueError(MP_ERROR_TEXT("mode"));
    }
    if (mode[0] == 'r' && rom_find(path) != NULL) {
        mp_raise_OSError(MP_EPERM);  // the ROM table is for import only
    }
    int fd = sh_open(path, sh_mode);
    if (fd < 0) {
        mp_raise_OSError(MP_ENOENT);
    }
    host_file_obj_t *o = mp_obj_malloc(host_file_obj_t, text ? &host_textfile_type : &host_file_type);
    o->fd = fd;
    return MP_OBJ_FROM_PTR(o);
}
MP_DEFINE_CONST_FUN_OBJ_KW(mp_builtin_open_obj, 1, mps2_open);

// ---- os: stat (size only), remove, rename, mkdir (existing only), getenv ----------------------

static mp_obj_t os_stat(mp_obj_t path_in) {
    const char *path = mp_obj_str_get_str(path_in);
    mp_int_t size;
    mp_int_t mode;
    const mps2_rom_file_t *f = rom_find(path);
    if (f != NULL) {
        size = f->len;
        mode = 0x8000;
    } else if (rom_is_dir(path)) {
        size = 0;
        mode = 0x4000;
    } else {
        mp_import_stat_t st = mp_import_stat(path);
        if (st == MP_IMPORT_STAT_NO_EXIST) {
            mp_raise_OSError(MP_ENOENT);
        }
        size = st == MP_IMPORT_STAT_DIR ? 0 : host_size(path);
        mode = st == MP_IMPORT_STAT_DIR ? 0x4000 : 0x8000;
    }
    mp_obj_t t[10];
    for (int i = 0; i < 10; i++) {
        t[i] = MP_OBJ_NEW_SMALL_INT(0);
    }
    t[0] = MP_OBJ_NEW_SMALL_INT(mode);
    t[6] = mp_obj_new_int(size);
    return mp_obj_new_tuple(10, t);
}
static MP_DEFINE_CONST_FUN_OBJ_1(os_stat_obj, os_stat);

static mp_obj_t os_remove(mp_obj_t path_in) {
    if (sh_remove(mp_obj_str_get_str(path_in)) != 0) {
        mp_raise_OSError(MP_ENOENT);
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_1(os_remove_obj, os_remove);

static mp_obj_t os_rename(mp_obj_t from_in, mp_obj_t to_in) {
    if (sh_rename(mp_obj_str_get_str(from_in), mp_obj_str_get_str(to_in)) != 0) {
        mp_raise_OSError(MP_ENOENT);
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_2(os_rename_obj, os_rename);

// Semihosting cannot create directories: the board's flash comes with them (the rig and
// `tcomp flash` create the table directory); an existing one is accepted, as mkdir -p would.
static mp_obj_t os_mkdir(mp_obj_t path_in) {
    if (mp_import_stat(mp_obj_str_get_str(path_in)) == MP_IMPORT_STAT_DIR) {
        mp_raise_OSError(MP_EEXIST);
    }
    mp_raise_OSError(MP_EPERM);
}
static MP_DEFINE_CONST_FUN_OBJ_1(os_mkdir_obj, os_mkdir);

static mp_obj_t os_getenv(size_t n_args, const mp_obj_t *args) {
    return n_args > 1 ? args[1] : mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(os_getenv_obj, 1, 2, os_getenv);

static const mp_rom_map_elem_t os_module_globals_table[] = {
    { MP_ROM_QSTR(MP_QSTR___name__), MP_ROM_QSTR(MP_QSTR_os) },
    { MP_ROM_QSTR(MP_QSTR_stat), MP_ROM_PTR(&os_stat_obj) },
    { MP_ROM_QSTR(MP_QSTR_remove), MP_ROM_PTR(&os_remove_obj) },
    { MP_ROM_QSTR(MP_QSTR_rename), MP_ROM_PTR(&os_rename_obj) },
    { MP_ROM_QSTR(MP_QSTR_mkdir), MP_ROM_PTR(&os_mkdir_obj) },
    { MP_ROM_QSTR(MP_QSTR_getenv), MP_ROM_PTR(&os_getenv_obj) },
};
static MP_DEFINE_CONST_DICT(os_module_globals, os_module_globals_table);

const mp_obj_module_t mp_module_os = {
    .base = { &mp_type_module },
    .globals = (mp_obj_dict_t *)&os_module_globals,
};
MP_REGISTER_MODULE(MP_QSTR_os, mp_module_os);
