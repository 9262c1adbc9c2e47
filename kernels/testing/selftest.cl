// Self-test kernel used by tests/test_cl.py: proves that -D specialisation and the build path work.
__kernel void scale_add(__global float *x, const float add)
{
    const size_t i = get_global_id(0);
    x[i] = SCALE * x[i] + add;
}
