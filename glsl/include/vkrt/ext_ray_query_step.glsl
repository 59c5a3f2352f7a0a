// One pass of vkrtRayQueryProceed's loop (vkrt/ext_ray_query.glsl), included there twice:
// with VKRT_RQ_FLAT_STEP 1, the pass for devices with a loop budget, which reaches no loop
// of its own (a primitive, an instance, one pop and one node step); with 0, the nested
// descent (Aila & Laine's while-while), which also walks kd-trees. Statements over
// Proceed's variables; no include guard.
#undef VKRT_RQ_GEOMETRY
#if VKRT_RQ_FLAT_STEP
#define VKRT_RQ_GEOMETRY(prim) vkrt_rq_geometry_entry_flat(prim)
#else
#define VKRT_RQ_GEOMETRY(prim) vkrt_geometry_entry(prim)
#endif
    if (steps > VKRT_STEP_LIMIT) {
        break;
    }
    if (in_bottom && leaf.x < leaf.y) {
        // The bottom leaf's next primitive.
        uint prim = VKRT_KD_REF(leaf.x);
        leaf.x++;
        steps++;
        uint iflags = inst.z >> 24u;
        uint n_tris = vkrt_scene_info.n_tris;
        VkrtRqHit h = VkrtRqHit(0u, 0.0, vec2(0.0), inst.x, prim, 0u, 0u, 0u, inst.y, inst.z);
        bool opaque;
        if (prim < n_tris) {
            if ((flags & VKRT_RAY_SKIP_TRIANGLES) != 0u) {
                continue;
            }
            vec3 p0, p1, p2;
            vkrt_triangle_at(prim, 0.0, p0, p1, p2);
            float t, u, v;
            bool front;
#ifdef VKRT_MOLLER_TRUMBORE
            bool hit = vkrt_hit_triangle_moller(r.o, r.d, p0, p1, p2, tmin, best_t, t, u, v);
            front = vkrt_dot3(vkrt_cross3(p1 - p0, p2 - p0), r.d) < 0.0;
#else
            bool hit = vkrt_hit_triangle_watertight_facing(r.o, sh, p0, p1, p2, tmin, best_t,
                                                            t, u, v, front);
#endif
            if (!hit) {
                continue;
            }
            front = front != ((iflags & VKRT_INSTANCE_FLIP_FACING) != 0u);
            uint cull = front ? VKRT_RAY_CULL_FRONT : VKRT_RAY_CULL_BACK;
            if ((iflags & VKRT_INSTANCE_CULL_DISABLE) == 0u && (flags & cull) != 0u) {
                continue;
            }
            uvec2 g = VKRT_RQ_GEOMETRY(prim);
            opaque = vkrt_rq_opaque(g.y, iflags, flags);
            h.t = t;
            h.barycentrics = vec2(u, v);
            h.geometry = g.y & 0x7fffffffu;
            h.primitive = prim - g.x;
            h.bits = (front ? 1u : 0u) | (opaque ? 2u : 0u);
            h.type = VKRT_CANDIDATE_TRIANGLE;
        } else {
            // A sphere or a box: the shader's to intersect, where the ray meets its box.
            if ((flags & VKRT_RAY_SKIP_AABBS) != 0u) {
                continue;
            }
            uint b = prim - n_tris;
            vec3 lo, hi;
            if (b < vkrt_scene_info.n_spheres) {
                vec4 sphere = vkrt_sphere_at(b, 0.0);
                lo = sphere.xyz - vec3(abs(sphere.w));
                hi = sphere.xyz + vec3(abs(sphere.w));
            } else {
                vkrt_aabb_at(b - vkrt_scene_info.n_spheres, lo, hi);
            }
            float t;
            if (!vkrt_rq_box_candidate(r.o, r.d, lo, hi, tmin, best_t, t)) {
                continue;
            }
            uvec2 g = VKRT_RQ_GEOMETRY(prim);
            opaque = vkrt_rq_opaque(g.y, iflags, flags);
            h.t = t;
            h.geometry = g.y & 0x7fffffffu;
            h.primitive = prim - g.x;
            h.bits = opaque ? 2u : 0u;
            h.type = VKRT_CANDIDATE_AABB;
        }
        if ((flags & (opaque ? VKRT_RAY_CULL_OPAQUE : VKRT_RAY_CULL_NO_OPAQUE)) != 0u) {
            continue;
        }
        if (kd && !opaque) {
            // A kd-tree may hold the triangle in several leaves: the shader would be
            // asked about it more than once. The query ends, exhausted, rather than
            // answer otherwise than the driver.
            end = VKRT_RQ_DONE | VKRT_RQ_EXHAUSTED;
            break;
        }
        if (!opaque || h.type == VKRT_CANDIDATE_AABB) {
            vkrt_rq_candidate[s] = h;
            found = true;
            end = 0u;
            break;
        }
        // An opaque triangle: committed where nearer (ties: the lower instance, then the
        // lower primitive, as vkrtTrace).
        VkrtRqHit c = vkrt_rq_committed[s];
        bool better = c.type == VKRT_COMMITTED_NONE || h.t < c.t
            || (h.t == c.t && (h.instance < c.instance || (h.instance == c.instance && prim < c.prim)));
        if (better) {
            h.type = VKRT_COMMITTED_TRIANGLE;
            vkrt_rq_committed[s] = h;
            best_t = h.t;
            if ((flags & VKRT_RAY_TERMINATE_ON_FIRST_HIT) != 0u) {
                end = VKRT_RQ_DONE;
                break;
            }
        }
        continue;
    }
    if (!in_bottom && leaf.z < leaf.w) {
        // The top leaf's next instance: into its bottom level, whose entries go above
        // the top level's.
        uint i = VKRT_KD_REF(leaf.z);
        leaf.z++;
        steps++;
        if (!vkrt_rq_enter(s, i, cull_mask)) {
            continue;
        }
        inst = vkrt_rq_instance[s];
        base = top;
        top = 0u;
        vkrt_rq_base = base;
        in_bottom = true;
        vkrt_use(vkrt_rq_bottom[s]);
        if (!vkrt_rq_walkable()) {
            end = VKRT_RQ_DONE | VKRT_RQ_EXHAUSTED;
            break;
        }
#if VKRT_RQ_FLAT_STEP
        if (!vkrt_rq_flat_serves()) {
            // Back in the top level, this instance again: the nested loop enters it.
            leaf.z--;
            steps--;
            top = base;
            base = 0u;
            vkrt_rq_base = 0u;
            in_bottom = false;
            vkrt_use(top_handle);
            nested = true;
            break;
        }
#endif
        wide = vkrt_scene_info.walk == VKRT_ACCEL_BVH_WIDE;
        r = VkrtRay(vkrt_rq_object_origin[s].xyz, tmin, vkrt_rq_object_direction[s].xyz, best_t);
        inv_d = vkrt_recip3(r.d);
        sh = vkrt_make_shear(r.d);
        cur = uvec2(0u);
        have = vkrt_primitive_count() != 0u;
        fresh = true;
#if !VKRT_RQ_FLAT_STEP
        kd = vkrt_scene_info.walk == VKRT_ACCEL_KDTREE;
        if (kd && have) {
            have = vkrt_rq_kd_start(r, tmin, best_t, kdw);
            node = 0u;
            n0 = uintBitsToFloat(kdw.x);
            n1 = uintBitsToFloat(kdw.y);
            scene_t1 = uintBitsToFloat(kdw.z);
            st_top = 0u;
            st_count = 0u;
            dropped = false;
        }
#endif
    }
#if VKRT_RQ_FLAT_STEP
    // One pop and one node step, and no loop: the node in hand, else the nearest entry.
    if (!fresh) {
        have = false;
        if (top > 0u) {
            VKRT_BVH_POP_ONE_ON(VKRT_RQ_AT)
            if (!have) {
                continue; // beyond the closest hit: dropped, the next entry next time
            }
        }
    }
    fresh = false;
    if (have && cur.y == 0u) {
        bool missed = false;
        if (wide) {
            VKRT_WIDE_NODE_STEP_ON(VKRT_RQ_AT, missed = true)
        } else {
            VKRT_BVH_NODE_STEP_ON(VKRT_RQ_AT, missed = true)
        }
        if (missed) {
            continue; // no child hit: a pop next
        }
        if (cur.y == 0u) {
            fresh = true; // an interior node in hand: its step next
            continue;
        }
    }
#else
    if (kd) {
        if (!fresh) {
            VKRT_KD_POP_ON(VKRT_RQ_KD, VKRT_RQ_KD_RING,
                           vkrt_rq_committed[s].type == VKRT_COMMITTED_NONE);
        }
        fresh = false;
        cur = uvec2(0u);
        if (have) {
            VKRT_KD_DESCEND_ON(VKRT_RQ_KD, VKRT_RQ_KD_RING);
            if (steps < VKRT_STEP_LIMIT) {
                steps++;
                if (nd.b == 0u) {
                    continue; // an empty leaf: the next cell
                }
                cur = uvec2(nd.a, nd.b);
            }
        }
    } else {
        if (!fresh) {
            VKRT_BVH_POP_ON(VKRT_RQ_AT);
        }
        fresh = false;
        if (wide) {
            VKRT_WIDE_DESCEND_ON(VKRT_RQ_AT);
        } else {
            VKRT_BVH_DESCEND_ON(VKRT_RQ_AT);
        }
    }
#endif
    if (!have) {
        if (in_bottom && (bits & VKRT_RQ_ONE_LEVEL) == 0u) {
            // The instance is done: back to the top level, whose entries end where the
            // bottom level's began.
            top = base;
            base = 0u;
            vkrt_rq_base = 0u;
            in_bottom = false;
            wide = false;
            kd = false;
            vkrt_use(top_handle);
            r = VkrtRay(vkrt_rq_origin[s].xyz, tmin, vkrt_rq_direction[s].xyz, best_t);
            inv_d = vkrt_recip3(r.d);
            sh = vkrt_make_shear(r.d);
            continue;
        }
        end = VKRT_RQ_DONE;
        break;
    }
    if (cur.y == 0u) {
        end = VKRT_RQ_DONE | VKRT_RQ_EXHAUSTED; // the step cap ended the descent
        break;
    }
    if (in_bottom) {
        leaf.xy = uvec2(cur.x, cur.x + cur.y);
    } else {
        leaf.zw = uvec2(cur.x, cur.x + cur.y);
    }
