/* Shared by the toy method's kernels. */
#define TOY_UP 1
