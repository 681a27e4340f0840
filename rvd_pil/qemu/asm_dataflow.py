"""Register dataflow of one disassembled instruction (LLVM syntax, as llvm-mc prints it), for A64
and A32/T32: which registers it reads and writes, and in which role. The cycle model
(rvd_pil/qemu/cycles.py) walks blocks with it to find how a corrected latency changes a block's critical
path, and classifies instructions for the Cortex-A8 model and for rewrites llvm-mca needs.

    >>> parse("aarch64", "fmadd\\td0, d1, d2, d0")
    Insn(mnemonic='fmadd', dests=('v0',), srcs=('v1', 'v2', 'v0'), acc='v0', ...)

Registers are normalised so that aliases meet: A64 w5/x5 -> r5, b/h/s/d/q/v5 -> v5; A32 sN and
dN -> dN (s2k and s2k+1 live in dk), qN -> d2N and d2N+1; condition flags -> nzcv, the FP status
flags -> fpscr. Memory is not tracked (as llvm-mca with -noalias: loads and stores never alias).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

FLAGS = "nzcv"
FPSCR = "fpscr"


@dataclass(frozen=True)
class Insn:
    text: str                      # the instruction as disassembled
    mnemonic: str                  # lower case, condition and .dt suffixes kept (e.g. "vmla.f64")
    dests: tuple[str, ...]
    srcs: tuple[str, ...]
    acc: str | None = None         # the accumulator source of a multiply-accumulate, if any
    is_load: bool = False
    is_store: bool = False
    is_branch: bool = False
    is_call: bool = False
    reglist: tuple[str, ...] = field(default=())  # registers of a {list} operand (ldm/push/vldm...)


_A64_COND = {"eq", "ne", "cs", "hs", "cc", "lo", "mi", "pl", "vs", "vc", "hi", "ls", "ge", "lt", "gt", "le",
             "al", "nv"}


def _split_operands(s: str) -> list[str]:
    """Top-level comma split (commas inside [] and {} stay)."""
    out, depth, cur = [], 0, []
    for ch in s:
        if ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        if ch == "," and depth == 0:
            out.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
    if cur and "".join(cur).strip():
        out.append("".join(cur).strip())
    return out


# ---- A64 ---------------------------------------------------------------------------------------
_A64_REG = re.compile(r"\b(?:([xw])(\d+)|([bhsdqv])(\d+)(?:\.\w+)?(?:\[\d+\])?|(sp|wsp)|(xzr|wzr)|(lr|fp))\b")


def _a64_regs(op: str) -> list[str]:
    regs = []
    for m in _A64_REG.finditer(op.lower()):
        if m.group(1):
            regs.append(f"r{m.group(2)}")
        elif m.group(3):
            regs.append(f"v{m.group(4)}")
        elif m.group(5):
            regs.append("sp")
        elif m.group(7):
            regs.append("r30" if m.group(7) == "lr" else "r29")
        # xzr/wzr: the zero register carries no dependency
    return regs


def _a64_list(op: str) -> list[str]:
    """Registers of an A64 {v0.2d, v1.2d} or {v0.2d-v3.2d} list."""
    inner = op[op.index("{") + 1:op.index("}")]
    rng = re.fullmatch(r"\s*v(\d+)\.\w+\s*-\s*v(\d+)\.\w+\s*", inner)
    if rng:
        a, b = int(rng.group(1)), int(rng.group(2))
        return [f"v{i % 32}" for i in range(a, a + ((b - a) % 32) + 1)]
    return _a64_regs(inner)


def _a64(text: str) -> Insn:
    parts = text.strip().split(None, 1)
    mn = parts[0].lower()
    ops = _split_operands(parts[1]) if len(parts) > 1 else []
    base = mn.split(".")[0]
    dests: list[str] = []
    srcs: list[str] = []
    acc = None
    reglist: list[str] = []
    is_load = is_store = is_branch = is_call = False

    mem_ops = [o for o in ops if o.startswith("[")]
    writeback = bool(mem_ops) and (mem_ops[0].endswith("!") or (ops and ops[-1] != mem_ops[0] and
                                                                 ops.index(mem_ops[0]) < len(ops) - 1))
    addr_regs = _a64_regs(mem_ops[0]) if mem_ops else []
    post_regs = []
    if mem_ops and ops.index(mem_ops[0]) < len(ops) - 1:  # post-index: [xN], #imm or [xN], xM
        post_regs = [r for o in ops[ops.index(mem_ops[0]) + 1:] for r in _a64_regs(o)]
    value_ops = [o for o in ops if o not in mem_ops]

    if base in ("b", "br", "ret", "cbz", "cbnz", "tbz", "tbnz", "bl", "blr", "braa", "retaa") or \
            (mn.startswith("b.") and mn[2:] in _A64_COND):
        is_branch = True
        is_call = base in ("bl", "blr")
        for o in ops:
            srcs += _a64_regs(o)
        if base == "ret" and not ops:
            srcs.append("r30")
        if mn.startswith("b."):
            srcs.append(FLAGS)
        if is_call:
            dests.append("r30")
    elif base.startswith("ld") or base in ("prfm", "prfum"):
        is_load = base.startswith("ld")
        lists = [o for o in value_ops if o.startswith("{")]
        if lists:
            dests = _a64_list(lists[0])
            reglist = list(dests)
        elif is_load:
            n_dest = 2 if base in ("ldp", "ldnp", "ldpsw", "ldxp", "ldaxp") else 1
            for o in value_ops[:n_dest]:
                dests += _a64_regs(o)
        srcs = addr_regs + post_regs
        if lists and "[" in (lists[0] + "".join(value_ops)) and re.search(r"\}\[\d+\]", lists[0]):
            srcs += dests  # ld1 {v0.d}[1]: lane insert reads the rest of the register
        if writeback and addr_regs:
            dests.append(addr_regs[0])
    elif base.startswith("st") and base not in ("stxr", "stlxr", "stxp", "stlxp"):
        is_store = True
        lists = [o for o in value_ops if o.startswith("{")]
        vals = _a64_list(lists[0]) if lists else [r for o in value_ops for r in _a64_regs(o)]
        reglist = vals if lists else []
        srcs = vals + addr_regs + post_regs
        if writeback and addr_regs:
            dests.append(addr_regs[0])
    elif base in ("stxr", "stlxr", "stxp", "stlxp"):
        is_store = True
        dests = _a64_regs(ops[0])
        srcs = [r for o in value_ops[1:] for r in _a64_regs(o)] + addr_regs
    elif base in ("cmp", "cmn", "tst", "fcmp", "fcmpe", "ccmp", "ccmn", "fccmp", "fccmpe"):
        srcs = [r for o in ops for r in _a64_regs(o)]
        if base in ("ccmp", "ccmn", "fccmp", "fccmpe"):
            srcs.append(FLAGS)
        dests = [FLAGS]
    elif base in ("svc", "nop", "hint", "dmb", "dsb", "isb", "yield", "brk", "hlt", "clrex"):
        pass
    elif base in ("msr",):
        srcs = [r for o in ops[1:] for r in _a64_regs(o)]
    elif base in ("mrs",):
        dests = _a64_regs(ops[0])
    else:
        if ops:
            dests = _a64_regs(ops[0])[:1]
            srcs = [r for o in ops[1:] for r in _a64_regs(o)]
        if base in ("fmadd", "fmsub", "fnmadd", "fnmsub", "madd", "msub", "smaddl", "umaddl", "smsubl",
                    "umsubl") and len(ops) == 4:
            acc = (_a64_regs(ops[3]) or [None])[0]
        if base in ("fmla", "fmls", "mla", "mls", "bfi", "bfxil", "bfm", "movk", "ins", "sli", "sri",
                    "fcmla", "sdot", "udot", "bsl", "bit", "bif", "ssra", "usra", "saba", "uaba"):
            srcs.append(dests[0] if dests else None)
            if base in ("fmla", "fmls", "mla", "mls") and dests:
                acc = dests[0]
        if base in ("mov",) and ops and "[" in ops[0]:  # mov v0.d[1], x1: lane insert
            srcs += dests
        if base in ("csel", "csinc", "csinv", "csneg", "cset", "csetm", "cinc", "cinv", "cneg", "fcsel", "adc",
                    "adcs", "sbc", "sbcs", "ngc", "ngcs"):
            srcs.append(FLAGS)
        if base in ("adds", "subs", "ands", "bics", "adcs", "sbcs", "negs", "ngcs"):
            dests.append(FLAGS)
    srcs = [s for s in srcs if s]
    return Insn(text=text.strip(), mnemonic=mn, dests=tuple(dict.fromkeys(dests)), srcs=tuple(srcs), acc=acc,
                is_load=is_load, is_store=is_store, is_branch=is_branch, is_call=is_call, reglist=tuple(reglist))


# ---- A32 / T32 ---------------------------------------------------------------------------------
_ARM_COND = ("eq", "ne", "cs", "hs", "cc", "lo", "mi", "pl", "vs", "vc", "hi", "ls", "ge", "lt", "gt", "le")
_ARM_REG = re.compile(r"\b(?:r(\d+)|(sp)|(lr)|(pc)|(ip)|(fp)|(sl)|(sb)|s(\d+)|d(\d+)|q(\d+))\b")


def _arm_regs(op: str) -> list[str]:
    regs = []
    for m in _ARM_REG.finditer(op.lower()):
        if m.group(1):
            regs.append(f"r{m.group(1)}")
        elif m.group(2):
            regs.append("r13")
        elif m.group(3):
            regs.append("r14")
        elif m.group(4):
            regs.append("r15")
        elif m.group(5):
            regs.append("r12")
        elif m.group(6):
            regs.append("r11")
        elif m.group(7):
            regs.append("r10")
        elif m.group(8):
            regs.append("r9")
        elif m.group(9):
            regs.append(f"d{int(m.group(9)) // 2}")
        elif m.group(10):
            regs.append(f"d{m.group(10)}")
        elif m.group(11):
            q = int(m.group(11))
            regs += [f"d{2 * q}", f"d{2 * q + 1}"]
    return regs


def _arm_list(op: str) -> list[str]:
    inner = op[op.index("{") + 1:op.index("}")]
    regs = []
    for item in inner.split(","):
        item = item.strip()
        rng = re.fullmatch(r"([rsd])(\d+)\s*-\s*[rsd](\d+)", item)
        if rng:
            kind, a, b = rng.group(1), int(rng.group(2)), int(rng.group(3))
            regs += _arm_regs(", ".join(f"{kind}{i}" for i in range(a, b + 1)))
        else:
            regs += _arm_regs(item)
    return list(dict.fromkeys(regs))


def _strip_arm_mnemonic(mn: str) -> tuple[str, str | None]:
    """(base without condition / width / data type, condition or None). "addeq.w" -> ("add", "eq")."""
    head = mn.split(".")[0]
    for c in _ARM_COND:
        if head.endswith(c) and len(head) > len(c) and head[:-len(c)] in _ARM_BASES_COND:
            return head[:-len(c)], c
    return head, None


# Bases that may carry a condition suffix in the disassembly (inside IT blocks or A32).
_ARM_BASES_COND = {
    "add", "adds", "sub", "subs", "mov", "movs", "mvn", "mvns", "and", "ands", "orr", "orrs", "eor", "eors",
    "bic", "bics", "rsb", "rsbs", "adc", "adcs", "sbc", "sbcs", "lsl", "lsls", "lsr", "lsrs", "asr", "asrs",
    "ror", "rors", "mul", "muls", "mla", "mls", "cmp", "cmn", "tst", "teq", "ldr", "ldrb", "ldrh", "ldrsb",
    "ldrsh", "ldrd", "str", "strb", "strh", "strd", "ldm", "stm", "ldmia", "stmia", "ldmdb", "stmdb", "push",
    "pop", "b", "bl", "bx", "blx", "movw", "movt", "uxtb", "uxth", "sxtb", "sxth", "ubfx", "sbfx", "bfi",
    "bfc", "clz", "umull", "smull", "umlal", "smlal", "orn", "vmov", "vadd", "vsub", "vmul", "vmla", "vmls",
    "vnmla", "vnmls", "vnmul", "vdiv", "vsqrt", "vabs", "vneg", "vcmp", "vcmpe", "vcvt", "vldr", "vstr",
    "vldmia", "vstmia", "vldmdb", "vstmdb", "vpush", "vpop", "vmrs", "vmsr", "it", "udiv", "sdiv", "rev",
    "nop", "mrc", "mcr", "rrx", "ldrex", "strex", "uxtab", "uxtah", "sxtab", "sxtah", "smmul", "smmla",
    "vfma", "vfms", "vfnma", "vfnms",
}


# Three-operand data processing that T32 also writes with two operands (rd is rn).
_ARM_TWO_OPERAND_SHORTHAND = {
    "add", "adds", "sub", "subs", "and", "ands", "orr", "orrs", "eor", "eors", "bic", "bics", "adc", "adcs",
    "sbc", "sbcs", "lsl", "lsls", "lsr", "lsrs", "asr", "asrs", "ror", "rors", "mul", "muls", "orn", "orns",
}


def _arm(text: str, conditional: bool) -> Insn:
    parts = text.strip().split(None, 1)
    mn = parts[0].lower()
    ops = _split_operands(parts[1]) if len(parts) > 1 else []
    base, cond = _strip_arm_mnemonic(mn)
    dests: list[str] = []
    srcs: list[str] = []
    acc = None
    reglist: list[str] = []
    is_load = is_store = is_branch = is_call = False
    mem_ops = [o for o in ops if o.startswith("[")]
    addr_regs = _arm_regs(mem_ops[0]) if mem_ops else []
    writeback = bool(mem_ops) and (mem_ops[0].endswith("!") or ops.index(mem_ops[0]) < len(ops) - 1)
    post_regs = [r for o in ops[ops.index(mem_ops[0]) + 1:] for r in _arm_regs(o)] if mem_ops else []
    value_ops = [o for o in ops if o not in mem_ops]
    lists = [o for o in ops if o.startswith("{")]

    if base in ("b", "bl", "bx", "blx", "cbz", "cbnz", "tbb", "tbh"):
        is_branch = True
        is_call = base in ("bl", "blx")
        srcs = [r for o in ops for r in _arm_regs(o)]
        if is_call:
            dests.append("r14")
        if cond or conditional:
            srcs.append(FLAGS)
    elif base in ("push", "vpush", "stm", "stmia", "stmdb", "stmib", "stmda", "vstmia", "vstmdb", "vstm"):
        is_store = True
        reglist = _arm_list(lists[0]) if lists else []
        base_reg = ["r13"] if base in ("push", "vpush") else _arm_regs(ops[0].rstrip("!"))[:1]
        srcs = reglist + base_reg
        if base in ("push", "vpush") or ops[0].endswith("!"):
            dests = base_reg
    elif base in ("pop", "vpop", "ldm", "ldmia", "ldmdb", "ldmib", "ldmda", "vldmia", "vldmdb", "vldm"):
        is_load = True
        reglist = _arm_list(lists[0]) if lists else []
        base_reg = ["r13"] if base in ("pop", "vpop") else _arm_regs(ops[0].rstrip("!"))[:1]
        dests = list(reglist)
        srcs = list(base_reg)
        if base in ("pop", "vpop") or ops[0].endswith("!"):
            dests += base_reg
        if "r15" in reglist:
            is_branch = True
    elif base.startswith("ld") or base in ("vldr", "vld1", "vld2", "vld3", "vld4", "pld"):
        is_load = base != "pld"
        if lists:
            dests = _arm_list(lists[0])
            reglist = list(dests)
        elif is_load:
            n = 2 if base in ("ldrd", "ldrexd") else 1
            dests = [r for o in value_ops[:n] for r in _arm_regs(o)]
        srcs = addr_regs + post_regs
        if writeback and addr_regs:
            dests.append(addr_regs[0])
        if "r15" in dests:
            is_branch = True
    elif base.startswith("st") or base in ("vstr", "vst1", "vst2", "vst3", "vst4"):
        is_store = True
        if base in ("strex", "strexb", "strexh", "strexd"):
            dests = _arm_regs(ops[0])
            value_ops = value_ops[1:]
        vals = _arm_list(lists[0]) if lists else [r for o in value_ops for r in _arm_regs(o)]
        reglist = vals if lists else []
        srcs = vals + addr_regs + post_regs
        if writeback and addr_regs:
            dests.append(addr_regs[0])
    elif base in ("cmp", "cmn", "tst", "teq"):
        srcs = [r for o in ops for r in _arm_regs(o)]
        dests = [FLAGS]
    elif base in ("vcmp", "vcmpe"):
        srcs = [r for o in ops for r in _arm_regs(o)]
        dests = [FPSCR]
    elif base == "vmrs":
        srcs = [FPSCR]
        dests = [FLAGS] if ops and ops[0].lower() == "apsr_nzcv" else _arm_regs(ops[0]) if ops else []
    elif base == "vmsr":
        srcs = _arm_regs(ops[-1]) if ops else []
        dests = [FPSCR]
    elif base in ("it", "nop", "svc", "dmb", "dsb", "isb", "bkpt", "udf", "yield"):
        if base == "it":
            srcs = [FLAGS]
    elif base == "vmov" and len(ops) == 3 and _arm_regs(ops[0]) and _arm_regs(ops[0])[0].startswith("r"):
        dests = _arm_regs(ops[0]) + _arm_regs(ops[1])    # vmov r0, r1, d0
        srcs = _arm_regs(ops[2])
    elif base == "vmov" and len(ops) == 3:
        dests = _arm_regs(ops[0])                          # vmov d0, r0, r1
        srcs = _arm_regs(ops[1]) + _arm_regs(ops[2])
    else:
        if ops:
            first = _arm_regs(ops[0])
            dests = first if ops[0].lower().startswith("q") else first[:1]   # q0 is d0 and d1
            srcs = [r for o in ops[1:] for r in _arm_regs(o)]
            if len(ops) == 2 and base in _ARM_TWO_OPERAND_SHORTHAND:
                srcs += dests  # Thumb "adds r0, #1": the destination is also the first source
        if base in ("vmla", "vmls", "vnmla", "vnmls", "vfma", "vfms", "vfnma", "vfnms"):
            acc = dests[0] if dests else None
            srcs += dests
        if base in ("mla", "mls", "smlal", "umlal", "smmla") and len(ops) == 4:
            acc = (_arm_regs(ops[3]) or [None])[0]
            if base in ("smlal", "umlal"):
                srcs += dests
        if base in ("movt", "bfi", "bfc"):
            srcs += dests
        if base == "vmov" and ops and "[" in ops[0]:
            srcs += dests
        if base in ("adc", "adcs", "sbc", "sbcs", "rrx"):
            srcs.append(FLAGS)
        if base.endswith("s") and base[:-1] in _ARM_BASES_COND and base not in ("cmps",) and base != "vabs":
            dests.append(FLAGS)
        if base in ("muls",):
            dests.append(FLAGS)
    if cond or conditional:
        # A predicated instruction may leave its destination unchanged: it reads it too.
        srcs += [d for d in dests if d not in srcs]
        if FLAGS not in srcs:
            srcs.append(FLAGS)
    srcs = [s for s in srcs if s]
    return Insn(text=text.strip(), mnemonic=mn, dests=tuple(dict.fromkeys(dests)), srcs=tuple(srcs), acc=acc,
                is_load=is_load, is_store=is_store, is_branch=is_branch, is_call=is_call, reglist=tuple(reglist))


def parse(arch: str, text: str, conditional: bool = False) -> Insn:
    """One instruction. `conditional`: an A32/T32 instruction inside an IT block (its condition is
    not in the mnemonic's own text position for every form)."""
    return _a64(text) if arch == "aarch64" else _arm(text, conditional)


def parse_block(arch: str, lines: list[str]) -> list[Insn]:
    """A block's instructions, with T32 IT blocks resolved (the instructions an IT covers are
    conditional)."""
    out, pending = [], 0
    for line in lines:
        mn = line.split(None, 1)[0].lower()
        if arch != "aarch64" and re.fullmatch(r"it[te]{0,3}", mn):
            out.append(_arm(line, False))
            pending = len(mn) - 1
            continue
        out.append(parse(arch, line, conditional=pending > 0))
        pending = max(0, pending - 1)
    return out
