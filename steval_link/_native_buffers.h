/* Buffer checks shared by steval-link's C loops (_st_mahony_native.c, estimators/_ekf_native.c). */
#ifndef STEVAL_NATIVE_BUFFERS_H
#define STEVAL_NATIVE_BUFFERS_H
#define PY_SSIZE_T_CLEAN
#include <Python.h>

/* Every loop zero-initialises its views and releases them all on one path: releasing a view never taken is a
 * no-op (PyBuffer_Release ignores obj == NULL, which a failed PyObject_GetBuffer leaves). */

/* get_buffer's nbytes for a view of whole rows of row_bytes each (any number of them) */
#define ROWS_OF(row_bytes) (-(Py_ssize_t)(row_bytes))

/* A C-contiguous view (writable when asked) of exactly nbytes, or of whole rows (nbytes = ROWS_OF(row bytes)): the
 * number of rows (1 for exactly nbytes), or -1 with a ValueError. */
static Py_ssize_t get_buffer(PyObject *obj, Py_buffer *view, int writable, Py_ssize_t nbytes, const char *what)
{
    Py_ssize_t n = 1;
    if (PyObject_GetBuffer(obj, view, (writable ? PyBUF_WRITABLE : 0) | PyBUF_C_CONTIGUOUS) < 0) return -1;
    if (nbytes < 0) {
        n = view->len / -nbytes;
        nbytes = -nbytes * n;
    }
    if (view->len != nbytes) {
        PyErr_Format(PyExc_ValueError, "%s: %zd bytes, expected %zd", what, view->len, nbytes);
        PyBuffer_Release(view);
        return -1;
    }
    return n;
}

/* Releases the n views of a loop; returns NULL (the error return of a loop whose arguments failed). */
static PyObject *release(Py_buffer *views, int n)
{
    int i;
    for (i = 0; i < n; i++) PyBuffer_Release(&views[i]);
    return NULL;
}
#endif
