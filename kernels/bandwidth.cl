/* Memory-bandwidth probe: a streaming copy, the ceiling a memory-bound kernel can reach.
 * One work-item per float4; every byte is read once and written once. */

__kernel void stream_copy(__global const float4* src, __global float4* dst)
{
    size_t i = get_global_id(0);
    dst[i] = src[i];
}
