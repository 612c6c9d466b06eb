/* A reduction with its barrier left out: each work-item reads the local value its
 * neighbour writes, with nothing between the write and the read. PoCL runs a
 * work-group's items one after another and returns the "right" sum; any parallel
 * device may not. tests/test_oclgrind.py: Oclgrind must report the race. */
__kernel void neighbour_sum(__global const float* in, __global float* out,
                            __local float* scratch) {
    int l = get_local_id(0), n = get_local_size(0);
    scratch[l] = in[get_global_id(0)];
    /* barrier(CLK_LOCAL_MEM_FENCE); -- missing */
    out[get_global_id(0)] = scratch[l] + scratch[(l + 1) % n];
}
