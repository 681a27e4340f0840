"""Cycle model: target cycles of each solve from its translation-block counts (the block-profile
plugin, rvd_pil/qemu/plugin/block_profile.c) priced per block with a pipeline model, plus a cache-miss
term, as an interval.

    >>> model = CycleModel(targets.load("rpi3"))
    >>> prof = read_profile(Path("run.blocks"))
    >>> costs = model.block_costs(exe, prof.blocks)          # llvm-mca, once per executable (cached)
    >>> model.region_cycles(prof.regions[0], costs)          # RegionCycles(low, nominal, high, ...)

Per block (once per executable and CPU, cached under build/cycles/):
  - disassembly with llvm-mc (LLVM syntax; T32 or A32 per the ELF's mapping symbols on armhf);
  - rewrites llvm-mca needs (calls as branches: llvm-mca charges a call 100 cycles; T32 IT
    instructions, which llvm-mca cannot schedule, as NOPs; load/store-multiple and push/pop as the
    single loads and stores they perform, pairs where the ISA has them) -- counted per block;
  - llvm-mca (Debian llvm-15) with the CPU's scheduling model: `cold` = cycles of one pass from an
    empty pipeline, `steady` = cycles per pass when the block repeats back to back;
  - the correction table of rvd_pil/qemu/cycle_models.toml where LLVM disagrees with published timings:
    the block's register dataflow (rvd_pil/qemu/asm_dataflow.py) is walked twice, with LLVM's and with
    the published latencies; the difference moves the critical path (cold) and the loop-carried
    recurrence (steady), and a non-pipelined unit bounds the steady state from below;
  - the Cortex-A8 (no LLVM model) uses its own stated model instead (a8_block_cycles).
Per solve: core cycles = sum over blocks of executions x cost, for steady and cold; memory cycles
= cache misses x penalty ranges of the CPU; low = steady + memory low, high = cold + memory high,
nominal = steady + memory midpoint. A board calibration (rvd_pil/qemu/calibration.toml, written by
rvd_pil/bench/calibrate.py) scales the nominal by the measured/model ratio of that CPU.

What the model ignores (said in the report too): dependencies between blocks (each block is
priced alone), branch mispredictions, hardware prefetch, TLB misses, the kernel (system calls,
interrupts), bus contention, and memory-level parallelism beyond the stated ranges.
"""
from __future__ import annotations

import fcntl
import gzip
import hashlib
import json
import math
import os
import re
import shutil
import subprocess
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from rvd_pil import paths

from . import asm_dataflow
from .targets import Target

MODELS = Path(__file__).with_name("cycle_models.toml")
CALIBRATION = Path(__file__).with_name("calibration.toml")
CACHE_DIR = paths.build_root() / "cycles"
LLVM_MC = "llvm-mc-15"
LLVM_MCA = "llvm-mca-15"
STEADY_ITERATIONS = 21
MODEL_VERSION = 3  # with the code of this module and asm_dataflow.py, keys the cache in build/cycles
CACHE_FIELDS = ("load_acc", "load_l1_miss", "load_l2_miss", "store_acc", "store_l1_miss", "store_l2_miss",
                "ifetch_lines", "ifetch_l1_miss", "ifetch_l2_miss", "l2_writebacks", "l1_writebacks")


# ---- the plugin's output -----------------------------------------------------------------------
@dataclass(frozen=True)
class Block:
    id: int
    vaddr: int
    n_insns: int
    data: bytes

    @property
    def key(self) -> str:
        """Identity across runs of the same executable: address and bytes."""
        return hashlib.sha1(self.vaddr.to_bytes(8, "little") + self.data).hexdigest()[:20]


@dataclass
class Region:
    kind: str                 # "R": a solve region, "P": the whole process
    step: int
    insns: int                # sum of count x block size (= the instruction counter's figure)
    cache: dict[str, int]     # CACHE_FIELDS (all zero when the plugin ran without the cache model)
    counts: dict[int, int]    # block id -> executions


PER_INSTRUCTION = "per-instruction"  # miss_rates key of the fallback rate
MISS_FIELDS = ("load_l1_miss", "load_l2_miss", "store_l1_miss", "store_l2_miss", "ifetch_l1_miss", "ifetch_l2_miss")


@dataclass
class Profile:
    header: str
    blocks: dict[int, Block]
    regions: list[Region]
    process: Region | None
    cache_on: bool
    block_misses: dict[int, tuple[int, ...]] = field(default_factory=dict)  # id -> MISS_FIELDS, whole process

    def miss_rates(self) -> dict[str, tuple[float, ...]]:
        """Misses per execution of each block (by block key) inside the solve regions: how a run
        without the cache model borrows this run's memory behaviour."""
        if not self.cache_on:
            raise ValueError("miss rates need a profile made with the cache model on")
        executions: dict[int, int] = {}
        for r in self.regions:
            for bid, n in r.counts.items():
                executions[bid] = executions.get(bid, 0) + n
        none = (0,) * len(MISS_FIELDS)
        rates = {self.blocks[bid].key: tuple(x / n for x in self.block_misses.get(bid, none))
                 for bid, n in executions.items()}
        # For blocks the borrowing run executes and this one did not: the solves' misses per instruction.
        insns = sum(r.insns for r in self.regions)
        rates[PER_INSTRUCTION] = tuple(sum(r.cache[f] for r in self.regions) / max(1, insns) for f in MISS_FIELDS)
        return rates


def read_profile(path: Path) -> Profile:
    """Parses a block-profile file (plain or .gz)."""
    path = Path(path)
    opener = gzip.open if path.suffix == ".gz" else open
    blocks: dict[int, Block] = {}
    regions: list[Region] = []
    process = None
    header = ""
    current: Region | None = None
    misses: dict[int, tuple[int, ...]] = {}
    with opener(path, "rt") as f:
        for line in f:
            tag = line[:1]
            if tag == "#":
                if not header:
                    header = line[1:].strip()
            elif tag == "B":
                _, bid, vaddr, n, data = line.split()
                blocks[int(bid)] = Block(int(bid), int(vaddr, 16), int(n), bytes.fromhex(data))
            elif tag in "RP":
                parts = line.split()
                nums = list(map(int, parts[1:]))
                current = Region(tag, nums[0], nums[1], dict(zip(CACHE_FIELDS, nums[2:2 + len(CACHE_FIELDS)])), {})
            elif tag == "M":
                nums = list(map(int, line.split()[1:]))
                misses[nums[0]] = tuple(nums[1:])
            elif tag == "C" and current is not None:
                for item in line.split()[1:]:
                    bid, cnt = item.split(":")
                    current.counts[int(bid)] = int(cnt)
                if current.kind == "R":
                    regions.append(current)
                else:
                    process = current
                current = None
    return Profile(header, blocks, regions, process, "cache on" in header, misses)


# ---- models ------------------------------------------------------------------------------------
def models() -> dict:
    with MODELS.open("rb") as f:
        return tomllib.load(f)["cpu"]


def calibrations() -> dict:
    if not CALIBRATION.exists():
        return {}
    with CALIBRATION.open("rb") as f:
        return tomllib.load(f).get("cpu", {})


@dataclass(frozen=True)
class Correction:
    mnemonic: re.Pattern
    operand: re.Pattern
    latency: float | None
    llvm_latency: float | None
    accumulate_latency: float | None
    llvm_accumulate_latency: float | None
    occupancy: float | None
    llvm_occupancy: float | None
    unit: str | None
    source: str
    how: str
    verified: bool
    retire_ooo: bool = False        # completes out of program order (an in-order core does not wait for it)
    llvm_retire_ooo: bool = False

    def matches(self, insn: asm_dataflow.Insn) -> bool:
        parts = insn.text.split(None, 1)
        first = parts[1].split(",")[0].strip().lower() if len(parts) > 1 else ""
        return bool(self.mnemonic.search(insn.mnemonic) and self.operand.search(first))


def _corrections(entry: dict) -> list[Correction]:
    out = []
    for c in entry.get("correction", []):
        out.append(Correction(re.compile(c["mnemonic"]), re.compile(c.get("operand", "")), c.get("latency"),
                              c.get("llvm_latency"), c.get("accumulate_latency"), c.get("llvm_accumulate_latency"),
                              c.get("occupancy"), c.get("llvm_occupancy"), c.get("unit"), " ".join(c["source"].split()),
                              c.get("how", ""), c.get("verified", True), c.get("retire_ooo", False),
                              c.get("llvm_retire_ooo", False)))
    return out


@dataclass(frozen=True)
class BlockCost:
    steady: float          # cycles per pass, block repeated back to back (corrected)
    cold: float            # cycles of one pass from an empty pipeline (corrected)
    mca_steady: float      # llvm-mca before corrections (0 for the A8 model)
    mca_cold: float
    rewritten: int = 0     # instructions rewritten for llvm-mca (calls, IT, load/store multiple)
    unmodelled: int = 0    # instructions llvm-mca could not take at all (priced 1 cycle each)
    corrected: int = 0     # instructions a correction applied to


@dataclass(frozen=True)
class RegionCycles:
    insns: int
    core_steady: float
    core_cold: float
    mem_low: float
    mem_high: float
    low: float
    nominal: float
    high: float
    calibrated: bool = False
    unmodelled_insns: int = 0
    misses: dict = field(default_factory=dict)  # the cache counts the memory term used (own or borrowed)

    def time_s(self, clock_hz: float) -> tuple[float, float, float]:
        return self.low / clock_hz, self.nominal / clock_hz, self.high / clock_hz


def _tool(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        raise RuntimeError(f"{name} not found: install Debian's llvm-15 (tools/install-deps pil)")
    return path


def llvm_version() -> str:
    out = subprocess.run([_tool(LLVM_MCA), "--version"], capture_output=True, text=True).stdout
    m = re.search(r"LLVM version (\S+)", out)
    return m.group(1) if m else "unknown"


# ---- disassembly -------------------------------------------------------------------------------
def _arm_modes(exe: Path) -> list[tuple[int, str]]:
    """Sorted (address, 'a' | 't' | 'd') mapping symbols of an ARM ELF: which code is A32 or T32."""
    out = subprocess.run([_tool("llvm-readelf-15"), "-s", "--wide", str(exe)], capture_output=True, text=True,
                         check=True).stdout
    marks = []
    for line in out.splitlines():
        parts = line.split()
        if len(parts) >= 8 and re.fullmatch(r"\$[atd](\..*)?", parts[-1]):
            marks.append((int(parts[1], 16), parts[-1][1]))
    return sorted(marks)


def _mode_at(marks: list[tuple[int, str]], addr: int) -> str:
    lo, hi = 0, len(marks)
    while lo < hi:
        mid = (lo + hi) // 2
        if marks[mid][0] <= addr:
            lo = mid + 1
        else:
            hi = mid
    return marks[lo - 1][1] if lo else "t"


_ENCODING = re.compile(r"(?:@|//)\s*encoding:\s*\[([^\]]*)\]")


# After each block an undefined instruction the block cannot contain: when one block fails to
# decode, the next still starts in step. (bytes, how llvm-mc prints it; "trap" is T32 UDF #254)
_SENTINEL = {"aarch64": (bytes.fromhex("efbe0000"), "udf\t#48879"),
             "thumb": (bytes.fromhex("fedefede"), "trap"),   # two, so one survives a mis-decode
             "arm": (bytes.fromhex("ffeefbe7"), "udf\t#48879")}


def _llvm_mc(triple: str, blocks: list[Block]) -> dict[int, list[str] | None]:
    """Disassembles the blocks in one llvm-mc call; a block whose bytes do not decode into exactly
    its instruction count maps to None."""
    if not blocks:
        return {}
    kind = "aarch64" if triple.startswith("aarch64") else "thumb" if triple.startswith("thumb") else "arm"
    sentinel, sentinel_text = _SENTINEL[kind]
    text = "\n".join(" ".join(f"0x{b:02x}" for b in blk.data + sentinel) for blk in blocks) + "\n"
    features = [] if kind == "aarch64" else ["-mattr=+neon,+vfp3"]
    proc = subprocess.run([_tool(LLVM_MC), "--disassemble", "--show-encoding", f"-triple={triple}", *features],
                          input=text, capture_output=True, text=True)
    chunks: list[list[tuple[str, int]]] = [[]]
    for line in proc.stdout.splitlines():
        m = _ENCODING.search(line)
        if not m:
            continue
        insn = line[:m.start()].strip()
        if re.sub(r"\s+", "\t", insn) == sentinel_text:
            if chunks[-1]:          # blocks are never empty: a second sentinel in a row is the same one
                chunks.append([])
            continue
        chunks[-1].append((insn, len([x for x in m.group(1).split(",") if x.strip()])))
    out: dict[int, list[str] | None] = {}
    for blk, got in zip(blocks, chunks):
        ok = len(got) == blk.n_insns and sum(n for _, n in got) == len(blk.data)
        out[blk.id] = [g for g, _ in got] if ok else None
    for blk in blocks[len(chunks):]:
        out[blk.id] = None
    return out


def disassemble(arch: str, exe: Path | None, blocks: list[Block]) -> dict[int, tuple[str, list[str] | None]]:
    """block id -> (triple, instruction lines or None)."""
    if arch == "aarch64":
        triple = "aarch64-linux-gnu"
        return {k: (triple, v) for k, v in _llvm_mc(triple, blocks).items()}
    marks = _arm_modes(exe) if exe is not None else []
    groups: dict[str, list[Block]] = {"thumbv7a-linux-gnueabihf": [], "armv7a-linux-gnueabihf": []}
    for b in blocks:
        groups["armv7a-linux-gnueabihf" if _mode_at(marks, b.vaddr) == "a" else "thumbv7a-linux-gnueabihf"].append(b)
    out = {}
    for triple, bl in groups.items():
        for k, v in _llvm_mc(triple, bl).items():
            out[k] = (triple, v)
    return out


# ---- rewrites for llvm-mca ---------------------------------------------------------------------
def _arm_reg_name(r: str) -> str:
    return {"r13": "sp", "r14": "lr", "r15": "pc"}.get(r, r)


def rewrite_for_mca(arch: str, lines: list[str], thumb: bool = True) -> tuple[list[str], int]:
    """Instructions llvm-mca cannot price as the core runs them, replaced by equivalents it can:
    returns (lines, number rewritten). Costs the rewrite stands for are in the module docstring."""
    out, n = [], 0
    for line in lines:
        if arch != "aarch64" and thumb:
            # A predicated T32 instruction (its IT may even sit in the previous block) keeps its
            # cost; llvm-mca takes it only without the IT, so without its condition.
            head, _, rest = line.partition("\t")
            stem, dot, suffix = head.partition(".")
            base, cond = asm_dataflow._strip_arm_mnemonic(stem.lower())
            if cond and base != "b":
                line = base + (dot + suffix if dot else "") + ("\t" + rest if rest else "")
        ins = asm_dataflow.parse(arch, line)
        mn = ins.mnemonic
        base = mn.split(".")[0]
        if arch == "aarch64":
            if base == "bl":
                out.append("b\t" + line.split(None, 1)[1]); n += 1
            elif base == "blr":
                out.append("br\t" + line.split(None, 1)[1]); n += 1
            else:
                out.append(line)
            continue
        # A32/T32
        if re.fullmatch(r"it[te]{0,3}", base):
            n += 1  # dropped: llvm-mca's A9 model has no IT (nor NOP); priced as no cycles
        elif base == "bl" or (base.startswith("bl") and base[2:] in ("", "eq", "ne") and not base.startswith("blx")):
            out.append("b\t" + line.split(None, 1)[1]); n += 1
        elif base.startswith("blx"):
            target = line.split(None, 1)[1]
            out.append(("bx\t" if target.strip().startswith("r") or target.strip() in ("lr", "ip") else "b\t") + target)
            n += 1
        elif ins.reglist and asm_dataflow._strip_arm_mnemonic(base)[0] in (
                "push", "pop", "ldm", "ldmia", "ldmdb", "stm", "stmia", "stmdb", "ldmib", "stmib", "ldmda", "stmda"):
            base = asm_dataflow._strip_arm_mnemonic(base)[0]
            regs = [_arm_reg_name(r) for r in ins.reglist]
            load = ins.is_load
            base_reg = "sp" if base in ("push", "pop") else _arm_reg_name(asm_dataflow._arm_regs(line.split(None, 1)[1])[0])
            ret = "pc" in regs
            regs = ["r12" if r == "pc" else r for r in regs]
            pairs = []
            plain = [r for r in regs if r not in ("sp", "pc")]
            while thumb and len(plain) >= 2:   # T32 LDRD/STRD take any two registers, A32 only even/odd pairs
                pairs.append((plain.pop(0), plain.pop(0)))
            op = "ldr" if load else "str"
            for k, (a, b) in enumerate(pairs):
                out.append(f"{op}d\t{a}, {b}, [{base_reg}, #{8 * k}]")
            for k, r in enumerate(plain + [r for r in regs if r == "sp"]):
                out.append(f"{op}\t{r}, [{base_reg}, #{8 * len(pairs) + 4 * k}]")
            if base in ("push", "pop") or "!" in line:
                out.append(f"{'add' if base != 'push' and 'db' not in base else 'sub'}\t{base_reg}, {base_reg}, #{4 * len(regs)}")
            if ret:
                out.append("bx\tr12")
            n += 1
        elif ins.reglist and base in ("vpush", "vpop", "vldmia", "vldmdb", "vstmia", "vstmdb", "vldm", "vstm"):
            load = ins.is_load
            base_reg = "sp" if base in ("vpush", "vpop") else _arm_reg_name(asm_dataflow._arm_regs(line.split(None, 1)[1])[0])
            op = "vldr" if load else "vstr"
            for k, r in enumerate(ins.reglist):
                out.append(f"{op}\t{r}, [{base_reg}, #{8 * k}]")
            if base in ("vpush", "vpop") or "!" in line:
                out.append(f"{'sub' if base == 'vpush' or 'db' in base else 'add'}\t{base_reg}, {base_reg}, #{8 * len(ins.reglist)}")
            n += 1
        else:
            out.append(line)
    return out, n


# ---- llvm-mca ----------------------------------------------------------------------------------
_MCA_BAD = re.compile(r"note: instruction:\s*(.*)")


def _mca_run(triple: str, cpu: str, regions: dict[str, list[str]], iterations: int) -> dict[str, dict]:
    """One llvm-mca call over many named regions: name -> {'cycles', 'rthroughput', 'uops',
    'dispatch', 'latencies'}. Raises McaReject(instruction) when an instruction cannot be priced."""
    src = []
    for name, lines in regions.items():
        src.append(f"# LLVM-MCA-BEGIN {name}")
        src += lines
        src.append("# LLVM-MCA-END")
    text = "\n".join(src) + "\n"
    features = [] if triple.startswith("aarch64") else ["-mattr=+neon,+vfp3"]
    cmd = [_tool(LLVM_MCA), f"-mtriple={triple}", f"-mcpu={cpu}", *features, f"-iterations={iterations}", "-json",
           "-instruction-info", "-resource-pressure=0"]
    proc = subprocess.run(cmd, input=text, capture_output=True, text=True)
    if proc.returncode != 0:
        # Either a parse error ("<stdin>:LINE:COL: error: ...") or a scheduling one ("note:
        # instruction: TEXT"): name the instruction so that the caller can set it aside.
        m = re.search(r"<stdin>:(\d+):\d+: error", proc.stderr)
        bad = src[int(m.group(1)) - 1].strip() if m else ""
        if not bad:
            m = _MCA_BAD.search(proc.stderr)
            bad = m.group(1).strip() if m else ""
        raise McaReject(bad, proc.stderr.strip().splitlines()[:3])
    data = json.loads(proc.stdout)
    out = {}
    for reg in data["CodeRegions"]:
        s = reg["SummaryView"]
        lat = [i["Latency"] for i in reg["InstructionInfoView"]["InstructionList"]]
        out[reg["Name"]] = {"cycles": s["TotalCycles"], "rthroughput": s["BlockRThroughput"],
                            "uops": s["TotaluOps"] / max(1, s["Iterations"]), "dispatch": s["DispatchWidth"],
                            "latencies": lat}
    return out


class McaReject(Exception):
    def __init__(self, instruction: str, stderr: list[str]):
        super().__init__(f"llvm-mca rejected '{instruction}': {' | '.join(stderr)}")
        self.instruction = instruction


def _mnemonic(line: str) -> str:
    return line.strip().split(None, 1)[0].lower() if line.strip() else ""


def _mca_blocks(triple: str, cpu: str, regions: dict[str, list[str]],
                known_unsupported: tuple[str, ...] = ()) -> tuple[dict, dict, set[str]]:
    """cold and steady llvm-mca results per region. Instructions llvm-mca rejects are set aside by
    mnemonic (and remembered per CPU in build/cycles/) so that one odd instruction does not stop
    the whole executable's pricing; returns the mnemonics set aside."""
    memo = CACHE_DIR / f"rejected-{cpu}-{triple}-{llvm_version()}.json"
    rejected: set[str] = set(json.loads(memo.read_text())) if memo.exists() else set()
    rejected |= set(known_unsupported)
    stand_in = "nop" if triple.startswith("aarch64") else "mov\tr0, r0"
    while True:
        clean = {k: [ln for ln in v if _mnemonic(ln) not in rejected] or [stand_in] for k, v in regions.items()}
        try:
            cold = _mca_run(triple, cpu, clean, 1)
            steady = _mca_run(triple, cpu, clean, STEADY_ITERATIONS)
            break
        except McaReject as e:
            bad = _mnemonic(e.instruction)
            if not bad or bad in rejected:
                raise
            rejected.add(bad)
    memo.parent.mkdir(parents=True, exist_ok=True)
    memo.write_text(json.dumps(sorted(rejected)))
    return cold, steady, rejected


# ---- corrections -------------------------------------------------------------------------------
def _family(ins: asm_dataflow.Insn) -> str:
    return ins.mnemonic.split(".")[0]


def _walk(insns: list[asm_dataflow.Insn], lat: list[float], acc_lat: list[float | None],
          units: list[tuple[str, float] | None], passes: int, in_order_width: int = 0,
          retire_ooo: list[bool] | None = None) -> float:
    """Cycles of `passes` back-to-back passes of the block by register dataflow and the busy time of
    the units the correction table names.

    in_order_width = 0: dataflow order (an out-of-order core): the longest dependency chain.
    in_order_width = W: in-order issue, at most W instructions per cycle, each waiting for its
    operands (and its unit), as a scoreboarded in-order pipeline does, and, unless `retire_ooo`
    marks it, writing back in program order (as llvm-mca's in-order pipeline does: an instruction
    waits rather than complete before an older one). The end is the last result."""
    ready: dict[str, tuple[float, str | None, float]] = {}
    unit_free: dict[str, float] = {}
    end = 0.0
    cycle, used = 0.0, 0
    last_wb = 0.0
    for _ in range(passes):
        for k, ins in enumerate(insns):
            start = 0.0
            for r in ins.srcs:
                got = ready.get(r)
                if got is None:
                    continue
                t_full, fam, t_acc = got
                start = max(start, t_acc if (r == ins.acc and fam == _family(ins)) else t_full)
            if units[k] is not None:
                start = max(start, unit_free.get(units[k][0], 0.0))
            if in_order_width:
                ordered = not (retire_ooo and retire_ooo[k])
                if ordered and start + lat[k] < last_wb:
                    start = last_wb - lat[k]
                if start > cycle:
                    cycle, used = start, 0
                if used >= in_order_width:
                    cycle, used = math.floor(cycle) + 1, 0
                start = cycle
                used += 1
                if ordered:
                    last_wb = max(last_wb, start + lat[k])
            if units[k] is not None:
                unit_free[units[k][0]] = start + units[k][1]
            a = acc_lat[k]
            for d in ins.dests:
                ready[d] = (start + lat[k], _family(ins) if a is not None else None,
                            start + (a if a is not None else lat[k]))
            end = max(end, start + lat[k])
    return end


def _unit_bound(units: list[tuple[str, float] | None]) -> float:
    """Busy cycles per pass of the busiest corrected unit."""
    busy: dict[str, float] = {}
    for u in units:
        if u is not None:
            busy[u[0]] = busy.get(u[0], 0.0) + u[1]
    return max(busy.values(), default=0.0)


def correct(insns: list[asm_dataflow.Insn], llvm_lat: list[float], corrections: list[Correction],
            mca_cold: float, mca_steady: float, rthroughput: float, uops: float, dispatch: float,
            in_order: bool, retire_ooo: re.Pattern | None = None) -> tuple[float, float, int]:
    """(cold, steady, instructions corrected): llvm-mca's figures moved by the published timings.

    The block is walked twice, with LLVM's and with the published latencies and unit busy times of
    the corrected instructions (every other instruction keeps llvm-mca's latency in both walks):
    in issue order on an in-order core, where every exposed stall counts, so the steady state and
    the cold pass move by the walks' difference; by dependency chains on an out-of-order core,
    where the corrected chain or unit replaces llvm-mca's steady state only if LLVM's version of
    it was what set that steady state. Never below the dispatch bound."""
    lat0, lat1 = list(llvm_lat), list(llvm_lat)
    acc0: list[float | None] = [None] * len(insns)
    acc1: list[float | None] = [None] * len(insns)
    unit0: list[tuple[str, float] | None] = [None] * len(insns)
    unit1: list[tuple[str, float] | None] = [None] * len(insns)
    # Classes that complete out of order in LLVM's model and in the published one alike.
    ooo0 = [bool(retire_ooo and retire_ooo.search(ins.mnemonic)) for ins in insns]
    ooo1 = list(ooo0)
    n = 0
    for k, ins in enumerate(insns):
        c = next((c for c in corrections if c.matches(ins)), None)
        if c is None:
            continue
        n += 1
        if c.latency is not None:
            lat0[k] = c.llvm_latency if c.llvm_latency is not None else llvm_lat[k]
            lat1[k] = c.latency
        if c.accumulate_latency is not None:
            acc0[k] = c.llvm_accumulate_latency
            acc1[k] = c.accumulate_latency
        if c.occupancy is not None and c.unit:
            unit0[k] = (c.unit, c.llvm_occupancy or 0.0)
            unit1[k] = (c.unit, c.occupancy)
        ooo0[k], ooo1[k] = c.llvm_retire_ooo, c.retire_ooo
    if n == 0:
        return mca_cold, mca_steady, 0
    floor = uops / dispatch if dispatch else 0.0
    if in_order:
        w = max(1, int(dispatch))
        p0, p1 = _walk(insns, lat0, acc0, unit0, 1, w, ooo0), _walk(insns, lat1, acc1, unit1, 1, w, ooo1)
        r0 = _walk(insns, lat0, acc0, unit0, 3, w, ooo0) - _walk(insns, lat0, acc0, unit0, 2, w, ooo0)
        r1 = _walk(insns, lat1, acc1, unit1, 3, w, ooo1) - _walk(insns, lat1, acc1, unit1, 2, w, ooo1)
        steady = max(mca_steady + (r1 - r0), floor)
    else:
        p0, p1 = _walk(insns, lat0, acc0, unit0, 1), _walk(insns, lat1, acc1, unit1, 1)
        r0 = _walk(insns, lat0, acc0, unit0, 3) - _walk(insns, lat0, acc0, unit0, 2)
        r1 = _walk(insns, lat1, acc1, unit1, 3) - _walk(insns, lat1, acc1, unit1, 2)
        u0, u1 = _unit_bound(unit0), _unit_bound(unit1)
        # llvm-mca's resource bound stands unless a corrected unit is what set it.
        resources = rthroughput - (u0 - u1) if u0 and u0 >= rthroughput - 0.5 else rthroughput
        if mca_steady <= r0 + 0.5:   # LLVM's version of a corrected chain or unit set the steady state
            steady = max(r1, resources, floor)
        else:
            steady = max(mca_steady, r1)
    cold = max(mca_cold + (p1 - p0), steady)
    return cold, steady, n


# ---- Cortex-A8 ---------------------------------------------------------------------------------
def a8_block_cycles(insns: list[asm_dataflow.Insn], vfp: dict[str, list[float]]) -> tuple[float, float]:
    """(steady, cold) cycles of a block on the Cortex-A8, by the stated model:

    - VFP data processing runs on the non-pipelined VFP coprocessor: each instruction occupies it
      for its Table 16.25 cycles (low, high), with no forwarding (Cortex-A8 TRM);
    - every other instruction (integer, loads and stores, VFP loads/stores and register moves,
      NEON) goes through the in-order dual-issue integer pipeline: 1/2 cycle each when paired
      (steady), 1 cycle each when not (cold);
    - steady: the two run concurrently, the block costs the busier of them (low VFP figures);
      cold: they do not overlap and the VFP figures are the high ones.
    Not modelled: NEON-to-ARM transfer stalls, load-use stalls, branch penalties."""
    vfp_low = vfp_high = 0.0
    integer = 0
    for ins in insns:
        base = ins.mnemonic.split(".")[0]
        is_vfp_dp = base in vfp and ".f64" in ins.mnemonic or (base in vfp and ".f32" in ins.mnemonic) or \
            (base == "vmov" and re.match(r"vmov(\.f64|\.f32)?$", ins.mnemonic) and
             all(r.startswith("d") for r in ins.dests + ins.srcs) and ins.dests)
        if is_vfp_dp and base in vfp:
            lo, hi = vfp[base]
            vfp_low += lo
            vfp_high += hi
        else:
            integer += 1
    steady = max(integer / 2.0, vfp_low)
    cold = integer + vfp_high
    return steady, cold


# ---- the model -----------------------------------------------------------------------------------
class CycleModel:
    """The cycle model of one target (its CPU and clock)."""

    def __init__(self, target: Target, cpu: str | None = None):
        self.target = target
        self.cpu = cpu or target.cpu
        all_models = models()
        if self.cpu not in all_models:
            raise ValueError(f"no cycle model for CPU {self.cpu!r} in {MODELS.name}; known: {', '.join(all_models)}")
        self.entry = all_models[self.cpu]
        self.corrections = _corrections(self.entry)
        self.cache_geometry = tuple(tuple(self.entry["cache"][k]) for k in ("l1d", "l1i", "l2"))
        self.calibration = calibrations().get(self.cpu)
        self.arch = target.arch

    @property
    def in_order(self) -> bool:
        return self.entry.get("issue", "in-order") == "in-order"

    @property
    def engine(self) -> str:
        return self.entry.get("engine", "llvm-mca")

    def fingerprint(self) -> str:
        """Changes when anything that prices blocks changes."""
        code = [Path(__file__).read_bytes(), Path(asm_dataflow.__file__).read_bytes()]
        text = json.dumps([MODEL_VERSION, self.cpu, self.entry, llvm_version(),
                           [hashlib.sha256(c).hexdigest() for c in code]], sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def _cache_file(self, exe: Path | None) -> Path:
        exe_id = hashlib.sha256(Path(exe).read_bytes()).hexdigest()[:16] if exe else "noexe"
        return CACHE_DIR / exe_id / f"{self.cpu}-{self.fingerprint()}.json"

    def block_costs(self, exe: Path | None, blocks: dict[int, Block]) -> dict[int, BlockCost]:
        """Cost of every block (by id of this profile), priced once per executable and kept in
        build/cycles/<executable hash>/ for every later profile of the same executable."""
        path = self._cache_file(exe)
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path.with_suffix(".lock"), "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            known: dict[str, list] = json.loads(path.read_text()) if path.exists() else {}
            todo = [b for b in blocks.values() if b.key not in known]
            if todo:
                known.update(self._price(exe, todo))
                tmp = path.with_suffix(f".{os.getpid()}.tmp")
                tmp.write_text(json.dumps(known))
                tmp.replace(path)
        return {b.id: BlockCost(*known[b.key]) for b in blocks.values()}

    def _price(self, exe: Path | None, blocks: list[Block]) -> dict[str, list]:
        dis = disassemble(self.arch, exe, blocks)
        out: dict[str, list] = {}
        by_triple: dict[str, dict[str, list[str]]] = {}
        parsed: dict[str, tuple[list[asm_dataflow.Insn], int]] = {}
        for b in blocks:
            triple, lines = dis[b.id]
            if lines is None:
                # Undecodable: priced one cycle per instruction, both ways, and counted.
                out[b.key] = [float(b.n_insns), float(b.n_insns), 0.0, 0.0, 0, b.n_insns, 0]
                continue
            if self.engine == "a8":
                insns = asm_dataflow.parse_block(self.arch, lines)
                steady, cold = a8_block_cycles(insns, self.entry["vfp"]["cycles"])
                out[b.key] = [steady, cold, 0.0, 0.0, 0, 0, 0]
                continue
            rewritten, n_rw = rewrite_for_mca(self.arch, lines, thumb=triple.startswith("thumb"))
            mca_triple = triple if self.arch != "aarch64" else self.entry["triple"]
            by_triple.setdefault(mca_triple, {})[f"b{b.key}"] = rewritten
            parsed[b.key] = (asm_dataflow.parse_block(self.arch, rewritten), n_rw)
        for triple, regions in by_triple.items():
            cold, steady, rejected = _mca_blocks(triple, self.entry["mca_cpu"], regions,
                                                 tuple(self.entry.get("mca_unsupported", ())))
            for name, lines in regions.items():
                key = name[1:]
                insns, n_rw = parsed[key]
                unmodelled = sum(1 for ln in lines if _mnemonic(ln) in rejected)
                c1 = cold[name]
                s_total = steady[name]["cycles"]
                mca_steady = (s_total - c1["cycles"]) / (STEADY_ITERATIONS - 1)
                mca_cold = float(c1["cycles"])
                kept = [ins for ins, ln in zip(insns, lines) if _mnemonic(ln) not in rejected]
                lat = c1["latencies"]
                if len(lat) != len(kept):  # the "nop" stand-in of an emptied region
                    kept, lat = [], []
                cold_c, steady_c, n_corr = correct(kept, lat, self.corrections, mca_cold, mca_steady,
                                                   c1["rthroughput"], c1["uops"], c1["dispatch"], self.in_order,
                                                   re.compile(self.entry["retire_ooo"]) if "retire_ooo" in self.entry else None)
                out[key] = [steady_c + unmodelled, cold_c + unmodelled, mca_steady, mca_cold, n_rw, unmodelled, n_corr]
        return out

    # -- per region ----------------------------------------------------------------------------
    def memory_cycles(self, cache: dict[str, int]) -> tuple[float, float]:
        """(low, high) cycles the cache misses add. low: load misses only (stores retire into the
        write buffer, instruction fetch streams ahead), at the low penalties; high: every miss,
        loads, stores and instruction fetch, at the high penalties."""
        mem = self.entry["memory"]
        l2_lo, l2_hi = mem["l2_hit_cycles"]
        dram_lo, dram_hi = (ns * 1e-9 * self.target.clock_hz for ns in mem["dram_ns"])
        load_l2_hits = cache["load_l1_miss"] - cache["load_l2_miss"]
        low = load_l2_hits * l2_lo + cache["load_l2_miss"] * (l2_lo + dram_lo)
        all_l1 = cache["load_l1_miss"] + cache["store_l1_miss"] + cache["ifetch_l1_miss"]
        all_l2 = cache["load_l2_miss"] + cache["store_l2_miss"] + cache["ifetch_l2_miss"]
        high = (all_l1 - all_l2) * l2_hi + all_l2 * (l2_hi + dram_hi)
        return low, high

    def region_cycles(self, region: Region, costs: dict[int, BlockCost],
                      borrowed: dict[int, tuple[float, ...]] | None = None) -> RegionCycles:
        """Cycles of one region. `borrowed`: block id -> misses per execution from another run of
        the same executable with the cache model on (miss_rates), used when this run had it off."""
        steady = cold = 0.0
        unmodelled = 0
        cache = dict(region.cache)
        for bid, n in region.counts.items():
            c = costs[bid]
            steady += n * c.steady
            cold += n * c.cold
            unmodelled += n * c.unmodelled
        if borrowed is not None:
            for f in MISS_FIELDS:
                cache[f] = 0.0
            for bid, n in region.counts.items():
                r = borrowed.get(bid)
                if r is not None:
                    for f, x in zip(MISS_FIELDS, r):
                        cache[f] += n * x
        mem_lo, mem_hi = self.memory_cycles(cache)
        low, high = steady + mem_lo, cold + mem_hi
        nominal = steady + 0.5 * (mem_lo + mem_hi)
        calibrated = False
        if self.calibration:
            factor = float(self.calibration["factor"])
            nominal *= factor
            low, high = min(low, nominal), max(high, nominal)
            calibrated = True
        return RegionCycles(region.insns, steady, cold, mem_lo, mem_hi, low, nominal, high, calibrated, unmodelled, cache)


def profile_summary(model: CycleModel, exe: Path | None, profile: Profile,
                    miss_rates: dict[str, tuple[float, ...]] | None = None) -> list[dict]:
    """One row per step (the marker's step number): instructions, core and memory cycles, interval,
    times. A guidance step that marks several solves (the phase QP, then a recovery QP) gets their
    sum, as the flight software's own instruction count does. `miss_rates` (by block key, from
    Profile.miss_rates of a run with the cache model): the memory term of a profile made without it."""
    used = {b for r in profile.regions for b in r.counts}  # the solves' blocks only: a third of the process's
    uncovered: set[int] = set()
    costs = model.block_costs(exe, {b: profile.blocks[b] for b in used})
    borrowed = None
    if not profile.cache_on:
        if miss_rates is None:
            raise ValueError("profile made without the cache model: pass the miss rates of a run with it")
        fallback = miss_rates.get(PER_INSTRUCTION)
        borrowed = {}
        for b in used:
            r = miss_rates.get(profile.blocks[b].key)
            if r is None and fallback is not None:
                r = tuple(x * profile.blocks[b].n_insns for x in fallback)
                uncovered.add(b)
            if r is not None:
                borrowed[b] = r
    rows = []
    clock = model.target.clock_hz
    for r in profile.regions:
        c = model.region_cycles(r, costs, borrowed)
        covered = 1.0 if borrowed is None else (  # instructions in blocks with rates of their own
            sum(n * profile.blocks[b].n_insns for b, n in r.counts.items() if b in borrowed and b not in uncovered)
            / max(1, r.insns))
        rows.append({"step": r.step, "instructions": r.insns, "cycles_low": c.low, "cycles_nominal": c.nominal,
                     "cycles_high": c.high, "core_steady": c.core_steady, "core_cold": c.core_cold,
                     "mem_low": c.mem_low, "mem_high": c.mem_high, "l1d_load_misses": c.misses["load_l1_miss"],
                     "l1d_store_misses": c.misses["store_l1_miss"], "l2_misses": c.misses["load_l2_miss"] +
                     c.misses["store_l2_miss"] + c.misses["ifetch_l2_miss"], "l1i_misses": c.misses["ifetch_l1_miss"],
                     "loads": r.cache["load_acc"], "stores": r.cache["store_acc"],
                     "target_us_low": c.low / clock * 1e6, "target_us_nominal": c.nominal / clock * 1e6,
                     "target_us_high": c.high / clock * 1e6, "calibrated": c.calibrated,
                     "unmodelled_insns": c.unmodelled_insns,
                     "memory_term": "borrowed miss rates" if borrowed is not None else "cache model",
                     "miss_rate_coverage": covered})
    by_step: dict[int, dict] = {}
    for row in rows:
        acc = by_step.get(row["step"])
        if acc is None:
            by_step[row["step"]] = dict(row)
            continue
        n0, n1 = acc["instructions"], row["instructions"]
        for k, v in row.items():
            if k == "miss_rate_coverage":
                acc[k] = (acc[k] * n0 + v * n1) / max(1, n0 + n1)
            elif isinstance(v, (int, float)) and not isinstance(v, bool) and k != "step":
                acc[k] += v
        acc["regions"] = acc.get("regions", 1) + 1
    for row in by_step.values():
        row.setdefault("regions", 1)
    return list(by_step.values())


def main(argv=None) -> int:
    import argparse
    import csv
    import sys

    from . import targets

    ap = argparse.ArgumentParser(prog="python -m rvd_pil.qemu.cycles", description=__doc__.split("\n\n")[0])
    ap.add_argument("profile", type=Path)
    ap.add_argument("--target", required=True)
    ap.add_argument("--cpu", default=None, help="CPU of the cycle model (default: the target's)")
    ap.add_argument("--exe", type=Path, default=None, help="the profiled executable (armhf: T32/A32 from its symbols)")
    a = ap.parse_args(argv)
    t = targets.load(a.target)
    model = CycleModel(t, a.cpu)
    prof = read_profile(a.profile)
    rows = profile_summary(model, a.exe, prof)
    w = csv.DictWriter(sys.stdout, fieldnames=list(rows[0]) if rows else ["step"])
    w.writeheader()
    w.writerows(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


def price_run(profile_path: Path, exe: Path, model: CycleModel, out_csv: Path,
              miss_rates_from: Path | None = None) -> Path:
    """Writes the cycle model's figures per solve region of a profile to `out_csv` (with the model's
    fingerprint in `out_csv`.json): computed again only when the profile or the model changed. The
    profile is compressed to PROFILE.gz once priced. A profile made with the cache model also gets
    its per-block miss rates in `out_csv` minus .csv + .miss-rates.json; a profile made without it
    takes them from `miss_rates_from` (such a file of a run of the same executable)."""
    import csv

    profile_path = Path(profile_path)
    gz = profile_path if profile_path.suffix == ".gz" else profile_path.with_name(profile_path.name + ".gz")
    src = profile_path if profile_path.exists() else gz
    if not src.exists():
        raise FileNotFoundError(f"no block profile at {profile_path}")
    rates_path = out_csv.with_suffix(".miss-rates.json")
    stamp = {"model": model.fingerprint(), "profile_bytes": src.stat().st_size, "cpu": model.cpu,
             "calibration": model.calibration,
             "miss_rates_from": None if miss_rates_from is None else str(miss_rates_from),
             "miss_rates_bytes": None if miss_rates_from is None else Path(miss_rates_from).stat().st_size}
    side = out_csv.with_name(out_csv.name + ".json")
    if out_csv.exists() and side.exists() and json.loads(side.read_text()).get("stamp") == stamp:
        return out_csv
    prof = read_profile(src)
    rates = None
    if prof.cache_on:
        rates_path.write_text(json.dumps(prof.miss_rates()))
    elif miss_rates_from is not None:
        rates = {k: tuple(v) for k, v in json.loads(Path(miss_rates_from).read_text()).items()}
    rows = profile_summary(model, exe, prof, rates)
    tmp = out_csv.with_name(out_csv.name + ".tmp")
    with tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else ["step"])
        w.writeheader()
        w.writerows(rows)
    tmp.replace(out_csv)
    side.write_text(json.dumps({"stamp": stamp}))
    if src == profile_path and profile_path.suffix != ".gz":
        with profile_path.open("rb") as fin, gzip.open(gz, "wb", compresslevel=6) as fout:
            shutil.copyfileobj(fin, fout)
        profile_path.unlink()
        stamp["profile_bytes"] = gz.stat().st_size
        side.write_text(json.dumps({"stamp": stamp}))
    return out_csv
