// select.poll over the stream protocol's MP_STREAM_POLL ioctl: any stream object (sys.stdin, a
// file, a socket, a UART) can be polled, on any of tcomp's ports. ipoll() yields one tuple made
// when the poller is made, so polling allocates nothing (the rig's serial port polls stdin inside
// the firmware cycle, under heap_lock).
#include "py/mperrno.h"
#include "py/mphal.h"
#include "py/runtime.h"
#include "py/stream.h"

#define MAX_ENTRIES (8)

typedef struct _poller_t {
    mp_obj_base_t base;
    size_t n;
    mp_obj_t objs[MAX_ENTRIES];
    mp_uint_t masks[MAX_ENTRIES];
    mp_uint_t ready[MAX_ENTRIES];
    size_t next;  // ipoll iteration position
    mp_obj_tuple_t *result;  // (obj, events), reused by ipoll
} poller_t;

static mp_uint_t poll_one(mp_obj_t obj, mp_uint_t mask) {
    const mp_stream_p_t *s = mp_get_stream_raise(obj, MP_STREAM_OP_IOCTL);
    int err;
    mp_uint_t r = s->ioctl(obj, MP_STREAM_POLL, mask, &err);
    if (r == MP_STREAM_ERROR) {
        return mask | MP_STREAM_POLL_ERR;
    }
    return r;
}

static size_t find(poller_t *self, mp_obj_t obj) {
    for (size_t i = 0; i < self->n; i++) {
        if (self->objs[i] == obj) {
            return i;
        }
    }
    return self->n;
}

static mp_obj_t poller_register(size_t n_args, const mp_obj_t *args) {
    poller_t *self = MP_OBJ_TO_PTR(args[0]);
    mp_uint_t mask = n_args > 2 ? mp_obj_get_int(args[2]) : (MP_STREAM_POLL_RD | MP_STREAM_POLL_WR);
    mp_get_stream_raise(args[1], MP_STREAM_OP_IOCTL);
    size_t i = find(self, args[1]);
    if (i == self->n) {
        if (self->n == MAX_ENTRIES) {
            mp_raise_ValueError(MP_ERROR_TEXT("too many objects to poll"));
        }
        self->objs[self->n++] = args[1];
    }
    self->masks[i] = mask;
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(poller_register_obj, 2, 3, poller_register);

static mp_obj_t poller_modify(mp_obj_t self_in, mp_obj_t obj, mp_obj_t mask) {
    poller_t *self = MP_OBJ_TO_PTR(self_in);
    size_t i = find(self, obj);
    if (i == self->n) {
        mp_raise_OSError(MP_ENOENT);
    }
    self->masks[i] = mp_obj_get_int(mask);
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_3(poller_modify_obj, poller_modify);

static mp_obj_t poller_unregister(mp_obj_t self_in, mp_obj_t obj) {
    poller_t *self = MP_OBJ_TO_PTR(self_in);
    size_t i = find(self, obj);
    if (i < self->n) {
        for (; i + 1 < self->n; i++) {
            self->objs[i] = self->objs[i + 1];
            self->masks[i] = self->masks[i + 1];
        }
        self->n--;
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_2(poller_unregister_obj, poller_unregister);

// Poll until something is ready or timeout_ms (-1: forever) passed; returns how many are ready.
static size_t poll_all(poller_t *self, size_t n_args, const mp_obj_t *args) {
    mp_int_t timeout = -1;
    if (n_args > 1 && args[1] != mp_const_none) {
        timeout = mp_obj_get_int(args[1]);
    }
    mp_uint_t start = mp_hal_ticks_ms();
    for (;;) {
        size_t count = 0;
        for (size_t i = 0; i < self->n; i++) {
            self->ready[i] = poll_one(self->objs[i], self->masks[i]);
            count += self->ready[i] != 0;
        }
        if (count || timeout == 0 || (timeout > 0 && (mp_int_t)(mp_hal_ticks_ms() - start) >= timeout)) {
            self->next = 0;
            return count;
        }
        mp_hal_delay_ms(1);
    }
}

static mp_obj_t poller_poll(size_t n_args, const mp_obj_t *args) {
    poller_t *self = MP_OBJ_TO_PTR(args[0]);
    size_t count = poll_all(self, n_args, args);
    mp_obj_t list = mp_obj_new_list(0, NULL);
    for (size_t i = 0; count && i < self->n; i++) {
        if (self->ready[i]) {
            mp_obj_t t[2] = {self->objs[i], MP_OBJ_NEW_SMALL_INT(self->ready[i])};
            mp_obj_list_append(list, mp_obj_new_tuple(2, t));
        }
    }
    return list;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(poller_poll_obj, 1, 2, poller_poll);

static mp_obj_t poller_ipoll(size_t n_args, const mp_obj_t *args) {
    poller_t *self = MP_OBJ_TO_PTR(args[0]);
    poll_all(self, n_args, args);
    return args[0];
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(poller_ipoll_obj, 1, 3, poller_ipoll);

static mp_obj_t poller_iternext(mp_obj_t self_in) {
    poller_t *self = MP_OBJ_TO_PTR(self_in);
    while (self->next < self->n) {
        size_t i = self->next++;
        if (self->ready[i]) {
            self->result->items[0] = self->objs[i];
            self->result->items[1] = MP_OBJ_NEW_SMALL_INT(self->ready[i]);
            self->ready[i] = 0;
            return MP_OBJ_FROM_PTR(self->result);
        }
    }
    return MP_OBJ_STOP_ITERATION;
}

static const mp_rom_map_elem_t poller_locals_table[] = {
    { MP_ROM_QSTR(MP_QSTR_register), MP_ROM_PTR(&poller_register_obj) },
    { MP_ROM_QSTR(MP_QSTR_unregister), MP_ROM_PTR(&poller_unregister_obj) },
    { MP_ROM_QSTR(MP_QSTR_modify), MP_ROM_PTR(&poller_modify_obj) },
    { MP_ROM_QSTR(MP_QSTR_poll), MP_ROM_PTR(&poller_poll_obj) },
    { MP_ROM_QSTR(MP_QSTR_ipoll), MP_ROM_PTR(&poller_ipoll_obj) },
};
static MP_DEFINE_CONST_DICT(poller_locals, poller_locals_table);

MP_DEFINE_CONST_OBJ_TYPE(
    poller_type, MP_QSTR_poll, MP_TYPE_FLAG_ITER_IS_ITERNEXT,
    iter, poller_iternext,
    locals_dict, &poller_locals);

static mp_obj_t select_poll(void) {
    poller_t *p = mp_obj_malloc(poller_t, &poller_type);
    p->n = 0;
    p->next = 0;
    mp_obj_t t[2] = {mp_const_none, mp_const_none};
    p->result = MP_OBJ_TO_PTR(mp_obj_new_tuple(2, t));
    return MP_OBJ_FROM_PTR(p);
}
static MP_DEFINE_CONST_FUN_OBJ_0(select_poll_obj, select_poll);

static const mp_rom_map_elem_t select_globals_table[] = {
    { MP_ROM_QSTR(MP_QSTR___name__), MP_ROM_QSTR(MP_QSTR_select) },
    { MP_ROM_QSTR(MP_QSTR_poll), MP_ROM_PTR(&select_poll_obj) },
    { MP_ROM_QSTR(MP_QSTR_POLLIN), MP_ROM_INT(MP_STREAM_POLL_RD) },
    { MP_ROM_QSTR(MP_QSTR_POLLOUT), MP_ROM_INT(MP_STREAM_POLL_WR) },
    { MP_ROM_QSTR(MP_QSTR_POLLERR), MP_ROM_INT(MP_STREAM_POLL_ERR) },
    { MP_ROM_QSTR(MP_QSTR_POLLHUP), MP_ROM_INT(MP_STREAM_POLL_HUP) },
};
static MP_DEFINE_CONST_DICT(select_globals, select_globals_table);

const mp_obj_module_t mp_module_select = {
    .base = { &mp_type_module },
    .globals = (mp_obj_dict_t *)&select_globals,
};
MP_REGISTER_EXTENSIBLE_MODULE(MP_QSTR_select, mp_module_select);
