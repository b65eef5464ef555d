// The MicroPython core (py/modsys.c, shared/runtime/pyexec.c) includes extmod/modplatform.h,
// which the sdist does not ship. tcomp's ports name their machine in mpconfigport.h
// (MICROPY_BANNER_MACHINE), so nothing is needed from it.
#ifndef TCOMP_EXTMOD_MODPLATFORM_H
#define TCOMP_EXTMOD_MODPLATFORM_H
#endif
