#!/usr/bin/env python3
"""slangc for the tests: the Slang compiler library that PyPI's slangpy wheel carries (no
slangc program ships there), driven through its C API with slangc's own arguments.

    slangc.py SOURCE -target spirv -entry main -stage compute -o OUT.spv

SLANG_LIB names the library (libslang-compiler.so.*); `./x setup` unpacks it and writes a
`slangc` script that calls this one (VKRT_SLANGC)."""
import ctypes
import os
import sys


def source_unknown(spirv):
    """OpSource Slang (source language 11) as OpSource Unknown: Debian 12's SPIR-V tools
    and validation layer (1.3.239) predate that language and refuse the module for it."""
    words = bytearray(spirv)
    i = 20
    while i + 8 <= len(words):
        first = int.from_bytes(words[i:i + 4], "little")
        count, opcode = first >> 16, first & 0xFFFF
        if count == 0:
            break
        if opcode == 3 and int.from_bytes(words[i + 4:i + 8], "little") == 11:
            words[i + 4:i + 8] = (0).to_bytes(4, "little")
        i += 4 * count
    return bytes(words)


def main():
    lib = ctypes.CDLL(os.environ["SLANG_LIB"])
    lib.spCreateSession.restype = ctypes.c_void_p
    lib.spCreateSession.argtypes = [ctypes.c_char_p]
    lib.spCreateCompileRequest.restype = ctypes.c_void_p
    lib.spCreateCompileRequest.argtypes = [ctypes.c_void_p]
    lib.spProcessCommandLineArguments.restype = ctypes.c_int
    lib.spProcessCommandLineArguments.argtypes = [
        ctypes.c_void_p, ctypes.POINTER(ctypes.c_char_p), ctypes.c_int]
    lib.spCompile.restype = ctypes.c_int
    lib.spCompile.argtypes = [ctypes.c_void_p]
    lib.spGetDiagnosticOutput.restype = ctypes.c_char_p
    lib.spGetDiagnosticOutput.argtypes = [ctypes.c_void_p]
    lib.spGetEntryPointCode.restype = ctypes.c_void_p
    lib.spGetEntryPointCode.argtypes = [
        ctypes.c_void_p, ctypes.c_int, ctypes.POINTER(ctypes.c_size_t)]

    args = sys.argv[1:]
    if "-o" not in args or args.index("-o") + 1 >= len(args):
        sys.exit("slangc.py: -o OUT is required")
    out = args[args.index("-o") + 1]
    session = lib.spCreateSession(None)
    request = lib.spCreateCompileRequest(session)
    argv = (ctypes.c_char_p * len(args))(*[a.encode() for a in args])
    if lib.spProcessCommandLineArguments(request, argv, len(args)) != 0:
        sys.stderr.write((lib.spGetDiagnosticOutput(request) or b"").decode())
        sys.exit(2)
    status = lib.spCompile(request)
    sys.stderr.write((lib.spGetDiagnosticOutput(request) or b"").decode())
    if status != 0:
        sys.exit(1)
    size = ctypes.c_size_t(0)
    code = lib.spGetEntryPointCode(request, 0, ctypes.byref(size))
    if not code or size.value == 0:
        sys.exit("slangc.py: the compiler produced no code")
    with open(out + ".partial", "wb") as f:
        f.write(source_unknown(ctypes.string_at(code, size.value)))
    os.replace(out + ".partial", out)


if __name__ == "__main__":
    main()
