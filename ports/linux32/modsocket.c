// socket: the little the HIL rig's DUT needs for its control channel (an AF_UNIX stream socket,
// connect() with a packed sockaddr as on the unix port), as a stream: read/readline/write.
#include <errno.h>
#include <sys/socket.h>
#include <unistd.h>

#include "py/runtime.h"
#include "py/stream.h"
#include "fdfile.h"

static mp_obj_t socket_make_new(const mp_obj_type_t *type, size_t n_args, size_t n_kw, const mp_obj_t *args);

static mp_obj_t socket_connect(mp_obj_t self_in, mp_obj_t addr_in) {
    fdfile_t *self = MP_OBJ_TO_PTR(self_in);
    mp_buffer_info_t addr;
    mp_get_buffer_raise(addr_in, &addr, MP_BUFFER_READ);
    int r;
    while ((r = connect(self->fd, (const struct sockaddr *)addr.buf, addr.len)) < 0 && errno == EINTR) {
        mp_handle_pending(true);
    }
    if (r < 0) {
        mp_raise_OSError(errno);
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_2(socket_connect_obj, socket_connect);

static const mp_rom_map_elem_t socket_locals_table[] = {
    { MP_ROM_QSTR(MP_QSTR_connect), MP_ROM_PTR(&socket_connect_obj) },
    { MP_ROM_QSTR(MP_QSTR_read), MP_ROM_PTR(&mp_stream_read_obj) },
    { MP_ROM_QSTR(MP_QSTR_readinto), MP_ROM_PTR(&mp_stream_readinto_obj) },
    { MP_ROM_QSTR(MP_QSTR_readline), MP_ROM_PTR(&mp_stream_unbuffered_readline_obj) },
    { MP_ROM_QSTR(MP_QSTR_write), MP_ROM_PTR(&mp_stream_write_obj) },
    { MP_ROM_QSTR(MP_QSTR_send), MP_ROM_PTR(&mp_stream_write_obj) },
    { MP_ROM_QSTR(MP_QSTR_recv), MP_ROM_PTR(&mp_stream_read1_obj) },
    { MP_ROM_QSTR(MP_QSTR_close), MP_ROM_PTR(&mp_stream_close_obj) },
    { MP_ROM_QSTR(MP_QSTR___del__), MP_ROM_PTR(&mp_stream_close_obj) },
};
static MP_DEFINE_CONST_DICT(socket_locals, socket_locals_table);

MP_DEFINE_CONST_OBJ_TYPE(
    socket_type, MP_QSTR_socket, MP_TYPE_FLAG_NONE,
    make_new, socket_make_new,
    protocol, &fdfile_binary_stream_p,
    locals_dict, &socket_locals);

// the stream functions of a binary file on the same descriptor
static mp_obj_t socket_make_new(const mp_obj_type_t *type, size_t n_args, size_t n_kw, const mp_obj_t *args) {
    (void)type;
    mp_arg_check_num(n_args, n_kw, 0, 3, false);
    int af = n_args > 0 ? mp_obj_get_int(args[0]) : AF_INET;
    int st = n_args > 1 ? mp_obj_get_int(args[1]) : SOCK_STREAM;
    int proto = n_args > 2 ? mp_obj_get_int(args[2]) : 0;
    int fd = socket(af, st | SOCK_CLOEXEC, proto);
    if (fd < 0) {
        mp_raise_OSError(errno);
    }
    fdfile_t *s = MP_OBJ_TO_PTR(fdfile_new(fd, true));
    s->base.type = &socket_type;
    return MP_OBJ_FROM_PTR(s);
}

static const mp_rom_map_elem_t mp_module_socket_globals_table[] = {
    { MP_ROM_QSTR(MP_QSTR___name__), MP_ROM_QSTR(MP_QSTR_socket) },
    { MP_ROM_QSTR(MP_QSTR_socket), MP_ROM_PTR(&socket_type) },
    { MP_ROM_QSTR(MP_QSTR_AF_UNIX), MP_ROM_INT(AF_UNIX) },
    { MP_ROM_QSTR(MP_QSTR_AF_INET), MP_ROM_INT(AF_INET) },
    { MP_ROM_QSTR(MP_QSTR_SOCK_STREAM), MP_ROM_INT(SOCK_STREAM) },
};
static MP_DEFINE_CONST_DICT(mp_module_socket_globals, mp_module_socket_globals_table);

const mp_obj_module_t mp_module_socket = {
    .base = { &mp_type_module },
    .globals = (mp_obj_dict_t *)&mp_module_socket_globals,
};
MP_REGISTER_MODULE(MP_QSTR_socket, mp_module_socket);
