/* Every work-item but the first writes its local slot, and every work-item reads the
 * first's: a read of local memory nobody wrote. tests/test_oclgrind.py: Oclgrind's
 * uninitialised-value check must report it. */
__kernel void read_unwritten(__global float* out, __local float* scratch) {
    int l = get_local_id(0);
    if (l > 0) scratch[l] = 1.0f;
    barrier(CLK_LOCAL_MEM_FENCE);
    out[get_global_id(0)] = scratch[0] + scratch[l];
}
