#version 460
// Gathers instance records given as an array of pointers (VkAccelerationStructureGeometry-
// InstancesDataKHR with arrayOfPointers: each entry the device address of a 64-byte
// VkAccelerationStructureInstanceKHR, 16-byte aligned) into one array, in the pointers'
// order, which the top level's build then reads as it reads an array of records (CPU twin:
// `instance_pointers_on_host` in src/accel/instances.rs). A null pointer gives a record of
// zeros: an instance naming no bottom level, never hit and counted by the build.
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require
layout(local_size_x_id = 0) in;

layout(buffer_reference, std430, buffer_reference_align = 8) readonly buffer Pointers {
    uvec2 p[];
};
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer Record {
    uvec4 w[4];
};

layout(set = 0, binding = 0, std430) writeonly buffer Out {
    uvec4 records[];
};

layout(push_constant) uniform Push {
    uvec2 pointers; // where the array of pointers lies
    uint count;     // records to gather
    uint first;     // the first record's texel in `records` (the range's offset / 16)
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count) {
        return;
    }
    uvec2 at = Pointers(pc.pointers).p[i];
    for (uint k = 0u; k < 4u; k++) {
        uvec4 v = uvec4(0u);
        if (at != uvec2(0u)) {
            v = Record(at).w[k];
        }
        records[pc.first + 4u * i + k] = v;
    }
}
