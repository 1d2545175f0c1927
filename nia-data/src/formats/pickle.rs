//! Our own Python pickle reader (protocols 0-5, the opcode set of docs/method.md "Data" and a
//! few more), with numpy arrays, numpy scalars and dtypes decoded natively.
//!
//! Decoding runs the pickle machine over an arena of mutable nodes: the memo and the stack
//! hold node ids, so `BUILD` mutating an object in place (numpy's `_reconstruct` followed by
//! `BUILD (1, shape, dtype, is_fortran, raw)`) is seen by every alias of it, e.g. the same
//! array referenced from two dict keys. After `STOP` the node graph is materialised into a
//! [`PyValue`] tree (aliases become copies, cycles are an error).
//!
//! Safety against hostile input: every length is checked against the remaining input before
//! anything is allocated, integer arithmetic is checked, the materialised tree is limited in
//! depth ([`MAX_DEPTH`]) and in the total size that aliasing may copy ([`ALIAS_COPY_BUDGET_MIN`]).

use std::borrow::Cow;
use std::collections::HashMap;

use super::npy::{array_data_fortran_to_c, checked_numel, Dtype, DtypeKind};
use super::{ArrayData, NdArray, PyValue};

/// Deepest nesting of containers accepted when building the value tree. Real files nest fewer
/// than 10 levels; the limit keeps the recursive materialisation well inside a thread's stack.
pub const MAX_DEPTH: usize = 256;
/// Minimum number of bytes that copies of aliased objects may add (an alias in the pickle
/// becomes a copy in the tree). The budget is the larger of this and
/// [`ALIAS_COPY_BUDGET_FACTOR`] times the input size, so a small hostile pickle that
/// references one list from itself many levels deep cannot blow up exponentially.
pub const ALIAS_COPY_BUDGET_MIN: u64 = 64 << 20;
/// See [`ALIAS_COPY_BUDGET_MIN`].
pub const ALIAS_COPY_BUDGET_FACTOR: u64 = 8;
/// Highest pickle protocol understood.
pub const HIGHEST_PROTOCOL: u8 = 5;

/// Why a pickle could not be decoded. `offset` is the byte offset of the offending opcode.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PickleError {
    #[error("pickle truncated at byte {offset}: {what} needs {needed} bytes, {available} left")]
    Truncated {
        offset: usize,
        what: &'static str,
        needed: usize,
        available: usize,
    },
    #[error("unknown pickle opcode 0x{opcode:02x} at byte {offset}")]
    UnknownOpcode { offset: usize, opcode: u8 },
    #[error("pickle opcode {op} at byte {offset} is not supported: {reason}")]
    Unsupported {
        offset: usize,
        op: &'static str,
        reason: String,
    },
    #[error("pickle opcode {op} at byte {offset}: {msg}")]
    Invalid {
        offset: usize,
        op: &'static str,
        msg: String,
    },
    #[error("pickle ended after {len} bytes without a STOP opcode")]
    NoStop { len: usize },
    #[error("pickle exceeds a safety limit: {msg}")]
    Limit { msg: String },
}

type Id = usize;
type Result<T> = std::result::Result<T, PickleError>;

/// numpy array under construction.
#[derive(Debug)]
enum ArrayNode {
    /// `_reconstruct(ndarray, (0,), b'b')` before its `BUILD`: numpy's empty int8 array.
    Pending,
    Numeric(NdArray),
    /// dtype `object`: element node ids in C order.
    Objects {
        shape: Vec<usize>,
        items: Vec<Id>,
    },
}

/// A decoded object in the arena.
#[derive(Debug)]
enum Node {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    Bytes(Vec<u8>),
    List(Vec<Id>),
    Tuple(Vec<Id>),
    Dict(Vec<(Id, Id)>),
    Set {
        frozen: bool,
        items: Vec<Id>,
    },
    Global {
        module: String,
        name: String,
    },
    /// `numpy.dtype(typestr, align, copy)`; `order` is set by its `BUILD` state.
    Dtype {
        typestr: String,
        order: Option<char>,
    },
    Array(ArrayNode),
    Object {
        class: String,
        args: Vec<Id>,
        state: Option<Id>,
    },
    /// Placeholder left behind once a node's content has been moved into the output tree.
    Taken,
}

impl Node {
    fn type_name(&self) -> &'static str {
        match self {
            Node::None => "None",
            Node::Bool(_) => "bool",
            Node::Int(_) => "int",
            Node::Float(_) => "float",
            Node::Str(_) => "str",
            Node::Bytes(_) => "bytes",
            Node::List(_) => "list",
            Node::Tuple(_) => "tuple",
            Node::Dict(_) => "dict",
            Node::Set { .. } => "set",
            Node::Global { .. } => "global",
            Node::Dtype { .. } => "numpy.dtype",
            Node::Array(_) => "ndarray",
            Node::Object { .. } => "object",
            Node::Taken => "taken",
        }
    }

    fn children(&self) -> Vec<Id> {
        match self {
            Node::List(v) | Node::Tuple(v) | Node::Set { items: v, .. } => v.clone(),
            Node::Dict(pairs) => pairs.iter().flat_map(|&(k, v)| [k, v]).collect(),
            Node::Array(ArrayNode::Objects { items, .. }) => items.clone(),
            Node::Object { args, state, .. } => args.iter().copied().chain(*state).collect(),
            _ => Vec::new(),
        }
    }
}

/// Decode a pickle into a Python value tree.
///
/// numpy arrays become [`PyValue::Array`] (C order, native values), numpy scalars become
/// `Int`/`Float`/`Bool`, Python 2 `str` becomes `Bytes`, sets become
/// `Object { class: "builtins.set", args: [List(items)] }`, and instances of other classes
/// (chumpy `Ch`, scipy sparse matrices) become [`PyValue::Object`] with their `BUILD` state.
/// Bytes after `STOP` are ignored, as Python does.
pub fn read_pickle(bytes: &[u8]) -> std::result::Result<PyValue, PickleError> {
    let mut m = Machine {
        input: bytes,
        pos: 0,
        op_start: 0,
        op: "",
        nodes: Vec::new(),
        stack: Vec::new(),
        marks: Vec::new(),
        memo: HashMap::new(),
    };
    let root = m.run()?;
    let budget =
        ALIAS_COPY_BUDGET_MIN.max(ALIAS_COPY_BUDGET_FACTOR.saturating_mul(bytes.len() as u64));
    Materialiser::new(m.nodes, root, budget).value(root, 0)
}

struct Machine<'a> {
    input: &'a [u8],
    pos: usize,
    /// Offset and name of the opcode being executed, for errors.
    op_start: usize,
    op: &'static str,
    nodes: Vec<Node>,
    stack: Vec<Id>,
    marks: Vec<usize>,
    memo: HashMap<u64, Id>,
}

impl<'a> Machine<'a> {
    // --- errors -------------------------------------------------------------------------------

    fn invalid(&self, msg: impl Into<String>) -> PickleError {
        PickleError::Invalid {
            offset: self.op_start,
            op: self.op,
            msg: msg.into(),
        }
    }

    fn unsupported(&self, reason: impl Into<String>) -> PickleError {
        PickleError::Unsupported {
            offset: self.op_start,
            op: self.op,
            reason: reason.into(),
        }
    }

    // --- input --------------------------------------------------------------------------------

    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8]> {
        let available = self.input.len().saturating_sub(self.pos);
        if n > available {
            return Err(PickleError::Truncated {
                offset: self.op_start,
                what,
                needed: n,
                available,
            });
        }
        let s = &self.input[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn arr<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N]> {
        let s = self.take(N, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    fn u8(&mut self, what: &'static str) -> Result<u8> {
        Ok(self.arr::<1>(what)?[0])
    }

    fn len_u32(&mut self, what: &'static str) -> Result<usize> {
        Ok(u32::from_le_bytes(self.arr(what)?) as usize)
    }

    fn len_u64(&mut self, what: &'static str) -> Result<usize> {
        let n = u64::from_le_bytes(self.arr(what)?);
        usize::try_from(n).map_err(|_| self.invalid(format!("length {n} does not fit in memory")))
    }

    /// Bytes up to (not including) the next newline, which is consumed.
    fn line(&mut self, what: &'static str) -> Result<&'a [u8]> {
        let rest = self.input.get(self.pos..).unwrap_or(&[]);
        match rest.iter().position(|&b| b == b'\n') {
            Some(n) => {
                let s = &rest[..n];
                self.pos += n + 1;
                Ok(s)
            }
            None => Err(PickleError::Truncated {
                offset: self.op_start,
                what,
                needed: rest.len() + 1,
                available: rest.len(),
            }),
        }
    }

    fn line_str(&mut self, what: &'static str) -> Result<&'a str> {
        let l = self.line(what)?;
        std::str::from_utf8(l).map_err(|_| self.invalid(format!("{what} is not valid text")))
    }

    /// A memo index written as a decimal text line (`PUT`, `GET`).
    fn memo_index_line(&mut self, what: &'static str) -> Result<u64> {
        let t = self.line_str(what)?;
        t.trim()
            .parse::<u64>()
            .map_err(|_| self.invalid("bad memo index"))
    }

    fn utf8(&self, b: &[u8]) -> Result<String> {
        String::from_utf8(b.to_vec()).map_err(|e| self.invalid(format!("invalid UTF-8: {e}")))
    }

    // --- stack, memo, arena -------------------------------------------------------------------

    fn push_node(&mut self, node: Node) -> Id {
        let id = self.nodes.len();
        self.nodes.push(node);
        self.stack.push(id);
        id
    }

    /// Pops an argument sequence and, below it, what it is applied to (`REDUCE`, `NEWOBJ`);
    /// `what` names the arguments in errors.
    fn pop_call(&mut self, what: &str) -> Result<(Id, Vec<Id>)> {
        let args = self.pop()?;
        let callee = self.pop()?;
        Ok((callee, self.seq_of(args, what)?))
    }

    fn pop(&mut self) -> Result<Id> {
        let floor = self.marks.last().copied().unwrap_or(0);
        if self.stack.len() <= floor {
            return Err(self.invalid("stack underflow"));
        }
        self.stack
            .pop()
            .ok_or_else(|| self.invalid("stack underflow"))
    }

    fn top(&self) -> Result<Id> {
        let floor = self.marks.last().copied().unwrap_or(0);
        if self.stack.len() <= floor {
            return Err(self.invalid("empty stack"));
        }
        self.stack
            .last()
            .copied()
            .ok_or_else(|| self.invalid("empty stack"))
    }

    /// Items pushed since the last MARK (the mark is removed).
    fn pop_mark(&mut self) -> Result<Vec<Id>> {
        let mark = self
            .marks
            .pop()
            .ok_or_else(|| self.invalid("no MARK on the stack"))?;
        if mark > self.stack.len() {
            return Err(self.invalid("MARK above the stack"));
        }
        Ok(self.stack.split_off(mark))
    }

    fn node(&self, id: Id) -> Result<&Node> {
        self.nodes
            .get(id)
            .ok_or_else(|| self.invalid("dangling reference"))
    }

    fn node_mut(&mut self, id: Id) -> Result<&mut Node> {
        let err = self.invalid("dangling reference");
        self.nodes.get_mut(id).ok_or(err)
    }

    fn put(&mut self, index: u64) -> Result<()> {
        let top = self.top()?;
        self.memo.insert(index, top);
        Ok(())
    }

    fn get(&mut self, index: u64) -> Result<()> {
        let id = *self
            .memo
            .get(&index)
            .ok_or_else(|| self.invalid(format!("memo {index} unset")))?;
        self.stack.push(id);
        Ok(())
    }

    fn str_of(&self, id: Id, what: &str) -> Result<String> {
        match self.node(id)? {
            Node::Str(s) => Ok(s.clone()),
            Node::Bytes(b) => Ok(String::from_utf8_lossy(b).into_owned()),
            other => {
                Err(self.invalid(format!("{what} must be a str, found {}", other.type_name())))
            }
        }
    }

    fn int_of(&self, id: Id, what: &str) -> Result<i64> {
        match self.node(id)? {
            Node::Int(n) => Ok(*n),
            Node::Bool(b) => Ok(*b as i64),
            other => Err(self.invalid(format!(
                "{what} must be an int, found {}",
                other.type_name()
            ))),
        }
    }

    fn seq_of(&self, id: Id, what: &str) -> Result<Vec<Id>> {
        match self.node(id)? {
            Node::Tuple(v) | Node::List(v) => Ok(v.clone()),
            other => Err(self.invalid(format!(
                "{what} must be a tuple, found {}",
                other.type_name()
            ))),
        }
    }

    fn class_of(&self, id: Id) -> Result<String> {
        match self.node(id)? {
            Node::Global { module, name } => Ok(format!("{module}.{name}")),
            other => Err(self.invalid(format!("expected a class, found {}", other.type_name()))),
        }
    }

    // --- the machine --------------------------------------------------------------------------

    fn run(&mut self) -> Result<Id> {
        loop {
            self.op_start = self.pos;
            let Some(&code) = self.input.get(self.pos) else {
                return Err(PickleError::NoStop {
                    len: self.input.len(),
                });
            };
            self.pos += 1;
            self.op = opcode_name(code);
            if code == b'.' {
                // STOP: the value on top of the stack.
                return self.pop();
            }
            self.execute(code)?;
        }
    }

    /// One opcode other than STOP, by family (the families' opcodes do not overlap).
    fn execute(&mut self, code: u8) -> Result<()> {
        if let Some(node) = self.number(code)? {
            self.push_node(node);
            return Ok(());
        }
        if let Some(node) = self.text(code)? {
            self.push_node(node);
            return Ok(());
        }
        if self.framing(code)?
            || self.container(code)?
            || self.memo_op(code)?
            || self.object(code)?
        {
            return Ok(());
        }
        Err(self.refused(code))
    }

    /// The protocol, framing and mark opcodes (PROTO, FRAME, MARK, POP, POP_MARK, DUP);
    /// false for any other opcode.
    fn framing(&mut self, code: u8) -> Result<bool> {
        match code {
            0x80 => {
                let v = self.u8("PROTO version")?;
                if v > HIGHEST_PROTOCOL {
                    return Err(self.unsupported(format!("protocol {v}")));
                }
            }
            0x95 => {
                // FRAME: the whole input is in memory; only the length is skipped.
                self.len_u64("FRAME length")?;
            }
            b'(' => self.marks.push(self.stack.len()),
            b'0' => {
                if self.marks.last() == Some(&self.stack.len()) {
                    self.marks.pop();
                } else {
                    self.pop()?;
                }
            }
            b'1' => {
                self.pop_mark()?;
            }
            b'2' => {
                let t = self.top()?;
                self.stack.push(t);
            }
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// The node of a constant or number opcode (None, booleans, the integer and float
    /// encodings); `None` for any other opcode.
    fn number(&mut self, code: u8) -> Result<Option<Node>> {
        Ok(Some(match code {
            b'N' => Node::None,
            0x88 => Node::Bool(true),
            0x89 => Node::Bool(false),
            b'J' => {
                let v = i32::from_le_bytes(self.arr("BININT")?);
                Node::Int(v as i64)
            }
            b'K' => {
                let v = self.u8("BININT1")?;
                Node::Int(v as i64)
            }
            b'M' => {
                let v = u16::from_le_bytes(self.arr("BININT2")?);
                Node::Int(v as i64)
            }
            0x8a => {
                let n = self.u8("LONG1 length")? as usize;
                let b = self.take(n, "LONG1 bytes")?;
                let v = self.long_from_le(b)?;
                Node::Int(v)
            }
            0x8b => {
                let n = i32::from_le_bytes(self.arr("LONG4 length")?);
                let n = usize::try_from(n).map_err(|_| self.invalid("negative length"))?;
                let b = self.take(n, "LONG4 bytes")?;
                let v = self.long_from_le(b)?;
                Node::Int(v)
            }
            b'G' => {
                let v = f64::from_be_bytes(self.arr("BINFLOAT")?);
                Node::Float(v)
            }
            b'I' => match self.line_str("INT text")? {
                "00" => Node::Bool(false),
                "01" => Node::Bool(true),
                t => Node::Int(self.parse_text_int(t)?),
            },
            b'L' => {
                let text = self.line_str("LONG text")?;
                let t = text.strip_suffix('L').unwrap_or(text);
                let v = self.parse_text_int(t)?;
                Node::Int(v)
            }
            b'F' => {
                let text = self.line_str("FLOAT text")?;
                let v: f64 = text
                    .trim()
                    .parse()
                    .map_err(|_| self.invalid(format!("bad float {text:?}")))?;
                Node::Float(v)
            }
            _ => return Ok(None),
        }))
    }

    /// The node of a string or bytes opcode; `None` for any other opcode.
    fn text(&mut self, code: u8) -> Result<Option<Node>> {
        Ok(Some(match code {
            b'X' => {
                let n = self.len_u32("BINUNICODE length")?;
                let b = self.take(n, "BINUNICODE data")?;
                let s = self.utf8(b)?;
                Node::Str(s)
            }
            0x8c => {
                let n = self.u8("SHORT_BINUNICODE length")? as usize;
                let b = self.take(n, "SHORT_BINUNICODE data")?;
                let s = self.utf8(b)?;
                Node::Str(s)
            }
            0x8d => {
                let n = self.len_u64("BINUNICODE8 length")?;
                let b = self.take(n, "BINUNICODE8 data")?;
                let s = self.utf8(b)?;
                Node::Str(s)
            }
            b'C' | b'U' => {
                let n = self.u8("short bytes length")? as usize;
                let b = self.take(n, "short bytes data")?.to_vec();
                Node::Bytes(b)
            }
            b'B' | b'T' => {
                // BINSTRING's length is signed in Python 2; negative is an error there too.
                let n = i32::from_le_bytes(self.arr("bytes length")?);
                let n = if code == b'T' {
                    usize::try_from(n).map_err(|_| self.invalid("negative length"))?
                } else {
                    n as u32 as usize
                };
                let b = self.take(n, "bytes data")?.to_vec();
                Node::Bytes(b)
            }
            0x8e | 0x96 => {
                let n = self.len_u64("bytes length")?;
                let b = self.take(n, "bytes data")?.to_vec();
                Node::Bytes(b)
            }
            _ => return Ok(None),
        }))
    }

    /// The container opcodes: empty containers, containers of the items since MARK, and
    /// additions to the container on top of the stack; false for any other opcode.
    fn container(&mut self, code: u8) -> Result<bool> {
        match code {
            b'}' => {
                self.push_node(Node::Dict(Vec::new()));
            }
            b']' => {
                self.push_node(Node::List(Vec::new()));
            }
            b')' => {
                self.push_node(Node::Tuple(Vec::new()));
            }
            0x8f => {
                self.push_node(Node::Set {
                    frozen: false,
                    items: Vec::new(),
                });
            }
            b'd' => {
                let items = self.pop_mark()?;
                let pairs = pairs_of(&items).ok_or_else(|| self.invalid("odd number of items"))?;
                self.push_node(Node::Dict(pairs));
            }
            b'l' => {
                let items = self.pop_mark()?;
                self.push_node(Node::List(items));
            }
            b't' => {
                let items = self.pop_mark()?;
                self.push_node(Node::Tuple(items));
            }
            0x91 => {
                let items = self.pop_mark()?;
                self.push_node(Node::Set {
                    frozen: true,
                    items,
                });
            }
            0x85..=0x87 => {
                let n = (code - 0x84) as usize;
                let floor = self.marks.last().copied().unwrap_or(0);
                if self.stack.len() < floor + n {
                    return Err(self.invalid("stack underflow"));
                }
                let items = self.stack.split_off(self.stack.len() - n);
                self.push_node(Node::Tuple(items));
            }
            b'a' => {
                let item = self.pop()?;
                let list = self.top()?;
                self.extend_list(list, vec![item])?;
            }
            b'e' => {
                let items = self.pop_mark()?;
                let list = self.top()?;
                self.extend_list(list, items)?;
            }
            b's' => {
                let v = self.pop()?;
                let k = self.pop()?;
                let d = self.top()?;
                self.extend_dict(d, vec![(k, v)])?;
            }
            b'u' => {
                let items = self.pop_mark()?;
                let pairs = pairs_of(&items).ok_or_else(|| self.invalid("odd number of items"))?;
                let d = self.top()?;
                self.extend_dict(d, pairs)?;
            }
            0x90 => {
                let items = self.pop_mark()?;
                let s = self.top()?;
                match self.node_mut(s)? {
                    Node::Set { items: set, .. } => set.extend(items),
                    other => {
                        let t = other.type_name();
                        return Err(self.invalid(format!("ADDITEMS to a {t}")));
                    }
                }
            }
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// The memo opcodes (PUT and GET in their encodings); false for any other opcode.
    fn memo_op(&mut self, code: u8) -> Result<bool> {
        match code {
            b'q' => {
                let i = self.u8("BINPUT index")?;
                self.put(i as u64)?;
            }
            b'r' => {
                let i = u32::from_le_bytes(self.arr("LONG_BINPUT index")?);
                self.put(i as u64)?;
            }
            0x94 => {
                let i = self.memo.len() as u64;
                self.put(i)?;
            }
            b'p' => {
                let i = self.memo_index_line("PUT index")?;
                self.put(i)?;
            }
            b'h' => {
                let i = self.u8("BINGET index")?;
                self.get(i as u64)?;
            }
            b'j' => {
                let i = u32::from_le_bytes(self.arr("LONG_BINGET index")?);
                self.get(i as u64)?;
            }
            b'g' => {
                let i = self.memo_index_line("GET index")?;
                self.get(i)?;
            }
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// The globals and object opcodes (GLOBAL, STACK_GLOBAL, REDUCE, NEWOBJ, NEWOBJ_EX, BUILD);
    /// false for any other opcode.
    fn object(&mut self, code: u8) -> Result<bool> {
        match code {
            b'c' => {
                let module = self.line_str("GLOBAL module")?.to_string();
                let name = self.line_str("GLOBAL name")?.to_string();
                self.push_node(Node::Global { module, name });
            }
            0x93 => {
                let name = self.pop()?;
                let module = self.pop()?;
                let name = self.str_of(name, "STACK_GLOBAL name")?;
                let module = self.str_of(module, "STACK_GLOBAL module")?;
                self.push_node(Node::Global { module, name });
            }
            b'R' => {
                let (func, args) = self.pop_call("REDUCE arguments")?;
                let node = self.reduce(func, args)?;
                self.push_node(node);
            }
            0x81 => {
                let (cls, args) = self.pop_call("NEWOBJ arguments")?;
                let node = self.instantiate(cls, args)?;
                self.push_node(node);
            }
            0x92 => {
                let _kwargs = self.pop()?;
                let (cls, args) = self.pop_call("NEWOBJ_EX arguments")?;
                let node = self.instantiate(cls, args)?;
                self.push_node(node);
            }
            b'b' => {
                let state = self.pop()?;
                let target = self.top()?;
                self.build(target, state)?;
            }
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// Why an opcode no family runs is refused: a feature this reader does not have, or an
    /// unknown opcode.
    fn refused(&self, code: u8) -> PickleError {
        match code {
            b'P' | b'Q' => self.unsupported("persistent ids need an external object store"),
            0x82..=0x84 => self.unsupported("the extension registry is not available"),
            0x97 | 0x98 => self.unsupported("out-of-band buffers are not available"),
            b'S' | b'V' | b'i' | b'o' => self.unsupported("protocol-0 text strings and instances"),
            _ => PickleError::UnknownOpcode {
                offset: self.op_start,
                opcode: code,
            },
        }
    }

    fn parse_text_int(&self, t: &str) -> Result<i64> {
        t.trim()
            .parse::<i64>()
            .map_err(|_| self.invalid(format!("bad or out-of-range integer {t:?}")))
    }

    /// Little-endian two's complement integer (LONG1/LONG4) that must fit in an i64.
    fn long_from_le(&self, b: &[u8]) -> Result<i64> {
        let Some(&last) = b.last() else { return Ok(0) };
        let negative = last & 0x80 != 0;
        let fill = if negative { 0xff } else { 0x00 };
        let mut buf = [fill; 8];
        for (i, &byte) in b.iter().enumerate() {
            match buf.get_mut(i) {
                Some(slot) => *slot = byte,
                None if byte == fill => {}
                None => return Err(self.unsupported("integer does not fit in 64 bits")),
            }
        }
        let v = i64::from_le_bytes(buf);
        if (v < 0) != negative {
            return Err(self.unsupported("integer does not fit in 64 bits"));
        }
        Ok(v)
    }

    fn extend_list(&mut self, list: Id, items: Vec<Id>) -> Result<()> {
        match self.node_mut(list)? {
            Node::List(v) => {
                v.extend(items);
                Ok(())
            }
            other => {
                let t = other.type_name();
                Err(self.invalid(format!("append to a {t}")))
            }
        }
    }

    fn extend_dict(&mut self, dict: Id, pairs: Vec<(Id, Id)>) -> Result<()> {
        match self.node_mut(dict)? {
            Node::Dict(v) => {
                v.extend(pairs);
                Ok(())
            }
            other => {
                let t = other.type_name();
                Err(self.invalid(format!("set item on a {t}")))
            }
        }
    }

    /// `NEWOBJ`: `cls.__new__(cls, *args)`.
    fn instantiate(&self, cls: Id, args: Vec<Id>) -> Result<Node> {
        let class = self.class_of(cls)?;
        Ok(match class.as_str() {
            "collections.OrderedDict" | "collections.defaultdict" => Node::Dict(Vec::new()),
            "builtins.set" | "__builtin__.set" => Node::Set {
                frozen: false,
                items: Vec::new(),
            },
            "builtins.list" | "__builtin__.list" => Node::List(Vec::new()),
            "builtins.dict" | "__builtin__.dict" => Node::Dict(Vec::new()),
            _ => Node::Object {
                class,
                args,
                state: None,
            },
        })
    }

    /// `REDUCE`: `func(*args)` for the callables numpy and Python's own pickler emit; other
    /// classes become generic objects.
    fn reduce(&self, func: Id, args: Vec<Id>) -> Result<Node> {
        let (module, name) = match self.node(func)? {
            Node::Global { module, name } => (module.as_str(), name.as_str()),
            other => {
                let t = other.type_name();
                return Err(self.unsupported(format!("calling a {t} (only globals are callable)")));
            }
        };
        let arg = |i: usize| -> Result<Id> {
            args.get(i).copied().ok_or_else(|| {
                self.invalid(format!(
                    "{module}.{name} needs argument {i}, got {}",
                    args.len()
                ))
            })
        };
        match (module, name) {
            ("numpy.core.multiarray" | "numpy._core.multiarray", "_reconstruct") => {
                Ok(Node::Array(ArrayNode::Pending))
            }
            ("numpy", "dtype") => {
                let typestr = self.str_of(arg(0)?, "dtype type string")?;
                Ok(Node::Dtype {
                    typestr,
                    order: None,
                })
            }
            ("numpy.core.multiarray" | "numpy._core.multiarray", "scalar") => {
                self.numpy_scalar(arg(0)?, args.get(1).copied())
            }
            ("numpy.core.numeric" | "numpy._core.numeric", "_frombuffer") => {
                // _frombuffer(buffer, dtype, shape, order) (protocol 5, in-band buffer).
                let dtype = self.dtype_of(arg(1)?)?;
                let shape = self.shape_of(arg(2)?)?;
                let order = self.str_of(arg(3)?, "_frombuffer order")?;
                let raw = self.raw_bytes_of(arg(0)?)?;
                let array = self.numeric_array(&dtype, shape, order == "F", &raw)?;
                Ok(Node::Array(ArrayNode::Numeric(array)))
            }
            ("_codecs", "encode") => {
                let s = self.str_of(arg(0)?, "_codecs.encode text")?;
                let encoding = match args.get(1) {
                    Some(&e) => self.str_of(e, "_codecs.encode encoding")?,
                    None => "utf-8".to_string(),
                };
                Ok(Node::Bytes(self.encode_text(&s, &encoding)?))
            }
            ("builtins" | "__builtin__", "bytes" | "bytearray") => match args.as_slice() {
                [] => Ok(Node::Bytes(Vec::new())),
                [b] => Ok(Node::Bytes(self.raw_bytes_of(*b)?.into_owned())),
                [s, e, ..] => {
                    let s = self.str_of(*s, "bytes text")?;
                    let e = self.str_of(*e, "bytes encoding")?;
                    Ok(Node::Bytes(self.encode_text(&s, &e)?))
                }
            },
            ("builtins" | "__builtin__", "set" | "frozenset") => {
                let items = match args.first() {
                    Some(&a) => self.seq_of(a, "set items")?,
                    None => Vec::new(),
                };
                Ok(Node::Set {
                    frozen: name == "frozenset",
                    items,
                })
            }
            ("collections", "OrderedDict") => {
                // OrderedDict(()) or OrderedDict([[k, v], ...]); items usually follow as SETITEMS.
                let mut pairs = Vec::new();
                if let Some(&a) = args.first() {
                    for item in self.seq_of(a, "OrderedDict items")? {
                        match self.seq_of(item, "OrderedDict item")?.as_slice() {
                            [k, v] => pairs.push((*k, *v)),
                            _ => return Err(self.invalid("OrderedDict item is not a pair")),
                        }
                    }
                }
                Ok(Node::Dict(pairs))
            }
            ("collections", "defaultdict") => Ok(Node::Dict(Vec::new())),
            ("copy_reg" | "copyreg", "_reconstructor") => {
                // Python 2 / protocol <2 object: _reconstructor(cls, base, base_state).
                let class = self.class_of(arg(0)?)?;
                Ok(Node::Object {
                    class,
                    args: Vec::new(),
                    state: None,
                })
            }
            ("copy_reg" | "copyreg", "__newobj__") => {
                let class = self.class_of(arg(0)?)?;
                Ok(Node::Object {
                    class,
                    args: args.get(1..).unwrap_or(&[]).to_vec(),
                    state: None,
                })
            }
            _ => Ok(Node::Object {
                class: format!("{module}.{name}"),
                args,
                state: None,
            }),
        }
    }

    fn encode_text(&self, s: &str, encoding: &str) -> Result<Vec<u8>> {
        match encoding.to_ascii_lowercase().replace('_', "-").as_str() {
            "latin1" | "latin-1" | "iso-8859-1" | "iso8859-1" | "l1" => s
                .chars()
                .map(|c| u8::try_from(c as u32).ok())
                .collect::<Option<Vec<u8>>>()
                .ok_or_else(|| self.invalid("character outside latin-1")),
            "utf-8" | "utf8" => Ok(s.as_bytes().to_vec()),
            "ascii" if s.is_ascii() => Ok(s.as_bytes().to_vec()),
            other => Err(self.unsupported(format!("text encoding {other:?}"))),
        }
    }

    fn dtype_of(&self, id: Id) -> Result<Dtype> {
        match self.node(id)? {
            Node::Dtype { typestr, order } => {
                let full = match order {
                    Some(c) => format!("{c}{typestr}"),
                    None => typestr.clone(),
                };
                Dtype::parse(&full).map_err(|e| self.unsupported(format!("dtype '{full}': {e}")))
            }
            other => Err(self.invalid(format!(
                "expected a numpy.dtype, found {}",
                other.type_name()
            ))),
        }
    }

    fn shape_of(&self, id: Id) -> Result<Vec<usize>> {
        self.seq_of(id, "shape")?
            .into_iter()
            .map(|d| {
                let n = self.int_of(d, "shape entry")?;
                usize::try_from(n).map_err(|_| self.invalid(format!("negative dimension {n}")))
            })
            .collect()
    }

    /// Raw bytes of a bytes node (borrowed: array payloads can be tens of megabytes).
    fn raw_bytes_of(&self, id: Id) -> Result<Cow<'_, [u8]>> {
        match self.node(id)? {
            Node::Bytes(b) => Ok(Cow::Borrowed(b)),
            // A Python 2 str read as unicode: numpy's latin-1 convention.
            Node::Str(s) => self.encode_text(s, "latin1").map(Cow::Owned),
            other => Err(self.invalid(format!("expected raw bytes, found {}", other.type_name()))),
        }
    }

    fn numeric_array(
        &self,
        dtype: &Dtype,
        shape: Vec<usize>,
        fortran: bool,
        raw: &[u8],
    ) -> Result<NdArray> {
        let numel = checked_numel(&shape)
            .ok_or_else(|| self.invalid(format!("shape {shape:?} overflows")))?;
        let data = dtype
            .decode(raw, numel)
            .map_err(|e| self.invalid(format!("array data: {e}")))?;
        let data = if fortran {
            array_data_fortran_to_c(data, &shape)
        } else {
            data
        };
        Ok(NdArray::new(shape, data))
    }

    /// `numpy.core.multiarray.scalar(dtype, raw)`: one element as a Python number.
    fn numpy_scalar(&self, dtype: Id, payload: Option<Id>) -> Result<Node> {
        let dtype = self.dtype_of(dtype)?;
        let payload = payload.ok_or_else(|| self.invalid("numpy scalar without data"))?;
        if dtype.kind == DtypeKind::Object {
            // scalar(dtype('O'), obj): the object itself; copy the node shallowly.
            return self.shallow_copy(payload);
        }
        let raw = self.raw_bytes_of(payload)?;
        let data = dtype
            .decode(&raw, 1)
            .map_err(|e| self.invalid(format!("numpy scalar: {e}")))?;
        Ok(match data {
            ArrayData::Bool(v) => Node::Bool(v.first().copied().unwrap_or(false)),
            ArrayData::F32(v) => Node::Float(v.first().copied().unwrap_or(0.0) as f64),
            ArrayData::F64(v) => Node::Float(v.first().copied().unwrap_or(0.0)),
            ArrayData::I8(v) => Node::Int(v.first().copied().unwrap_or(0) as i64),
            ArrayData::I16(v) => Node::Int(v.first().copied().unwrap_or(0) as i64),
            ArrayData::I32(v) => Node::Int(v.first().copied().unwrap_or(0) as i64),
            ArrayData::I64(v) => Node::Int(v.first().copied().unwrap_or(0)),
            ArrayData::U8(v) => Node::Int(v.first().copied().unwrap_or(0) as i64),
            ArrayData::U16(v) => Node::Int(v.first().copied().unwrap_or(0) as i64),
            ArrayData::U32(v) => Node::Int(v.first().copied().unwrap_or(0) as i64),
            ArrayData::U64(v) => Node::Int(
                i64::try_from(v.first().copied().unwrap_or(0))
                    .map_err(|_| self.unsupported("uint64 scalar above i64::MAX"))?,
            ),
            ArrayData::Object(v) => match v.into_iter().next() {
                Some(PyValue::Str(s)) => Node::Str(s),
                Some(PyValue::Bytes(b)) => Node::Bytes(b),
                _ => return Err(self.invalid("numpy scalar of unsupported dtype")),
            },
        })
    }

    fn shallow_copy(&self, id: Id) -> Result<Node> {
        Ok(match self.node(id)? {
            Node::None => Node::None,
            Node::Bool(b) => Node::Bool(*b),
            Node::Int(n) => Node::Int(*n),
            Node::Float(f) => Node::Float(*f),
            Node::Str(s) => Node::Str(s.clone()),
            Node::Bytes(b) => Node::Bytes(b.clone()),
            Node::List(v) => Node::List(v.clone()),
            Node::Tuple(v) => Node::Tuple(v.clone()),
            Node::Dict(v) => Node::Dict(v.clone()),
            other => {
                return Err(
                    self.unsupported(format!("object numpy scalar of {}", other.type_name()))
                )
            }
        })
    }

    /// `BUILD`: set the state of the object on top of the stack, in place.
    fn build(&mut self, target: Id, state: Id) -> Result<()> {
        match self.node(target)? {
            Node::Array(_) => {
                let built = self.array_from_state(state)?;
                *self.node_mut(target)? = Node::Array(built);
                Ok(())
            }
            Node::Dtype { .. } => {
                // State (version, byteorder, subarray, names, fields, elsize, alignment, flags).
                let items = self.seq_of(state, "dtype state")?;
                let order_id = *items
                    .get(1)
                    .ok_or_else(|| self.invalid("dtype state too short"))?;
                let order = self.str_of(order_id, "dtype byte order")?;
                let c = match order.as_str() {
                    "<" | ">" | "|" | "=" => order.chars().next(),
                    other => return Err(self.invalid(format!("dtype byte order {other:?}"))),
                };
                if let Node::Dtype { order, .. } = self.node_mut(target)? {
                    *order = c;
                }
                Ok(())
            }
            Node::Object { .. } => {
                if let Node::Object { state: s, .. } = self.node_mut(target)? {
                    *s = Some(state);
                }
                Ok(())
            }
            // OrderedDict/defaultdict instance attributes: nothing we keep.
            Node::Dict(_) | Node::List(_) | Node::Set { .. } => {
                match self.node(state)? {
                    Node::None => Ok(()),
                    Node::Dict(v) if v.is_empty() => Ok(()),
                    other => Err(self
                        .unsupported(format!("BUILD state {} on a container", other.type_name()))),
                }
            }
            other => Err(self.invalid(format!("BUILD on a {}", other.type_name()))),
        }
    }

    /// ndarray state `(version, shape, dtype, is_fortran, raw)` (version 1) or the older
    /// `(shape, dtype, is_fortran, raw)`.
    fn array_from_state(&self, state: Id) -> Result<ArrayNode> {
        let items = self.seq_of(state, "ndarray state")?;
        let fields = match items.as_slice() {
            [_version, shape, dtype, fortran, raw] => [*shape, *dtype, *fortran, *raw],
            [shape, dtype, fortran, raw] => [*shape, *dtype, *fortran, *raw],
            _ => {
                return Err(self.invalid(format!(
                    "ndarray state must have 4 or 5 items, found {}",
                    items.len()
                )))
            }
        };
        let [shape_id, dtype_id, fortran_id, raw_id] = fields;
        let shape = self.shape_of(shape_id)?;
        let dtype = self.dtype_of(dtype_id)?;
        let fortran = self.int_of(fortran_id, "is_fortran")? != 0;
        let numel = checked_numel(&shape)
            .ok_or_else(|| self.invalid(format!("shape {shape:?} overflows")))?;
        if dtype.kind == DtypeKind::Object {
            let items = self.seq_of(raw_id, "object array items")?;
            if items.len() != numel {
                return Err(self.invalid(format!(
                    "object array of shape {shape:?} needs {numel} items, found {}",
                    items.len()
                )));
            }
            let items = if fortran {
                super::npy::fortran_to_c(&items, &shape)
            } else {
                items
            };
            return Ok(ArrayNode::Objects { shape, items });
        }
        let raw = self.raw_bytes_of(raw_id)?;
        Ok(ArrayNode::Numeric(
            self.numeric_array(&dtype, shape, fortran, &raw)?,
        ))
    }
}

fn pairs_of(items: &[Id]) -> Option<Vec<(Id, Id)>> {
    if items.len() % 2 == 1 {
        return None;
    }
    Some(items.chunks_exact(2).map(|c| (c[0], c[1])).collect())
}

/// Turns the node graph into a value tree: each node is converted once; nodes referenced more
/// than once are cached and copied for the other references (within the copy budget).
struct Materialiser {
    nodes: Vec<Node>,
    /// References to each node not yet consumed (edges from all nodes plus the root).
    remaining: Vec<u32>,
    cache: HashMap<Id, (PyValue, u64)>,
    visiting: Vec<bool>,
    copied: u64,
    budget: u64,
}

impl Materialiser {
    fn new(nodes: Vec<Node>, root: Id, budget: u64) -> Self {
        let mut remaining = vec![0u32; nodes.len()];
        for node in &nodes {
            for child in node.children() {
                if let Some(r) = remaining.get_mut(child) {
                    *r = r.saturating_add(1);
                }
            }
        }
        if let Some(r) = remaining.get_mut(root) {
            *r = r.saturating_add(1);
        }
        let visiting = vec![false; nodes.len()];
        Self {
            nodes,
            remaining,
            cache: HashMap::new(),
            visiting,
            copied: 0,
            budget,
        }
    }

    fn limit(msg: impl Into<String>) -> PickleError {
        PickleError::Limit { msg: msg.into() }
    }

    fn value(&mut self, id: Id, depth: usize) -> Result<PyValue> {
        Ok(self.value_with_cost(id, depth)?.0)
    }

    /// The value of node `id` and its approximate size in bytes (for the copy budget).
    fn value_with_cost(&mut self, id: Id, depth: usize) -> Result<(PyValue, u64)> {
        if depth > MAX_DEPTH {
            return Err(Self::limit(format!(
                "containers nest deeper than {MAX_DEPTH} levels"
            )));
        }
        let remaining = self
            .remaining
            .get_mut(id)
            .ok_or_else(|| Self::limit("dangling node"))?;
        *remaining = remaining.saturating_sub(1);
        let last_use = *remaining == 0;
        if let Some((_, cost)) = self.cache.get(&id) {
            let cost = *cost;
            if last_use {
                if let Some(entry) = self.cache.remove(&id) {
                    return Ok(entry);
                }
            }
            self.copied = self.copied.saturating_add(cost);
            if self.copied > self.budget {
                return Err(Self::limit(format!(
                    "copies of shared objects exceed {} bytes",
                    self.budget
                )));
            }
            let (v, c) = self.cache.get(&id).ok_or_else(|| Self::limit("cache"))?;
            return Ok((v.clone(), *c));
        }
        match self.visiting.get(id) {
            Some(false) => {}
            _ => {
                return Err(Self::limit(
                    "recursive (self-referencing) structures are not supported",
                ))
            }
        }
        self.visiting[id] = true;
        let node = std::mem::replace(&mut self.nodes[id], Node::Taken);
        let result = self.convert(node, depth);
        self.visiting[id] = false;
        let (value, cost) = result?;
        if !last_use {
            // More references will come: keep a copy for them (counts against the budget).
            self.copied = self.copied.saturating_add(cost);
            if self.copied > self.budget {
                return Err(Self::limit(format!(
                    "copies of shared objects exceed {} bytes",
                    self.budget
                )));
            }
            self.cache.insert(id, (value.clone(), cost));
        }
        Ok((value, cost))
    }

    fn many(&mut self, ids: &[Id], depth: usize, cost: &mut u64) -> Result<Vec<PyValue>> {
        let mut out = Vec::with_capacity(ids.len());
        for &c in ids {
            let (v, k) = self.value_with_cost(c, depth + 1)?;
            *cost = cost.saturating_add(k);
            out.push(v);
        }
        Ok(out)
    }

    fn convert(&mut self, node: Node, depth: usize) -> Result<(PyValue, u64)> {
        const NODE_COST: u64 = 32;
        let mut cost = NODE_COST;
        let value = match node {
            Node::None => PyValue::None,
            Node::Bool(b) => PyValue::Bool(b),
            Node::Int(n) => PyValue::Int(n),
            Node::Float(f) => PyValue::Float(f),
            Node::Str(s) => {
                cost += s.len() as u64;
                PyValue::Str(s)
            }
            Node::Bytes(b) => {
                cost += b.len() as u64;
                PyValue::Bytes(b)
            }
            Node::List(v) => PyValue::List(self.many(&v, depth, &mut cost)?),
            Node::Tuple(v) => PyValue::Tuple(self.many(&v, depth, &mut cost)?),
            Node::Set { frozen, items } => {
                let items = self.many(&items, depth, &mut cost)?;
                let class = if frozen {
                    "builtins.frozenset"
                } else {
                    "builtins.set"
                };
                PyValue::Object {
                    class: class.into(),
                    args: vec![PyValue::List(items)],
                    state: Box::new(PyValue::None),
                }
            }
            Node::Dict(pairs) => {
                let mut out = Vec::with_capacity(pairs.len());
                for (k, v) in pairs {
                    let (kv, kc) = self.value_with_cost(k, depth + 1)?;
                    let (vv, vc) = self.value_with_cost(v, depth + 1)?;
                    cost = cost.saturating_add(kc).saturating_add(vc);
                    out.push((kv, vv));
                }
                PyValue::Dict(out)
            }
            Node::Global { module, name } => PyValue::Global { module, name },
            Node::Dtype { typestr, order } => PyValue::Object {
                class: "numpy.dtype".into(),
                args: vec![PyValue::Str(format!("{}{typestr}", order.unwrap_or('=')))],
                state: Box::new(PyValue::None),
            },
            Node::Array(ArrayNode::Pending) => {
                PyValue::Array(NdArray::new(vec![0], ArrayData::I8(Vec::new())))
            }
            Node::Array(ArrayNode::Numeric(a)) => {
                cost = cost.saturating_add(estimated_bytes(&a.data));
                PyValue::Array(a)
            }
            Node::Array(ArrayNode::Objects { shape, items }) => {
                let items = self.many(&items, depth, &mut cost)?;
                PyValue::Array(NdArray::new(shape, ArrayData::Object(items)))
            }
            Node::Object { class, args, state } => {
                let args = self.many(&args, depth, &mut cost)?;
                let state = match state {
                    Some(s) => {
                        let (v, c) = self.value_with_cost(s, depth + 1)?;
                        cost = cost.saturating_add(c);
                        v
                    }
                    None => PyValue::None,
                };
                PyValue::Object {
                    class,
                    args,
                    state: Box::new(state),
                }
            }
            Node::Taken => return Err(Self::limit("internal: node converted twice")),
        };
        Ok((value, cost))
    }
}

fn estimated_bytes(data: &ArrayData) -> u64 {
    let per = match data {
        ArrayData::I8(_) | ArrayData::U8(_) | ArrayData::Bool(_) => 1,
        ArrayData::I16(_) | ArrayData::U16(_) => 2,
        ArrayData::F32(_) | ArrayData::I32(_) | ArrayData::U32(_) => 4,
        _ => 8,
    };
    (data.len() as u64).saturating_mul(per)
}

/// Opcode names (pickletools spelling) for error messages.
pub fn opcode_name(code: u8) -> &'static str {
    match code {
        b'(' => "MARK",
        b'.' => "STOP",
        b'0' => "POP",
        b'1' => "POP_MARK",
        b'2' => "DUP",
        b'F' => "FLOAT",
        b'I' => "INT",
        b'J' => "BININT",
        b'K' => "BININT1",
        b'L' => "LONG",
        b'M' => "BININT2",
        b'N' => "NONE",
        b'P' => "PERSID",
        b'Q' => "BINPERSID",
        b'R' => "REDUCE",
        b'S' => "STRING",
        b'T' => "BINSTRING",
        b'U' => "SHORT_BINSTRING",
        b'V' => "UNICODE",
        b'X' => "BINUNICODE",
        b'a' => "APPEND",
        b'b' => "BUILD",
        b'c' => "GLOBAL",
        b'd' => "DICT",
        b'}' => "EMPTY_DICT",
        b'e' => "APPENDS",
        b'g' => "GET",
        b'h' => "BINGET",
        b'i' => "INST",
        b'j' => "LONG_BINGET",
        b'l' => "LIST",
        b']' => "EMPTY_LIST",
        b'o' => "OBJ",
        b'p' => "PUT",
        b'q' => "BINPUT",
        b'r' => "LONG_BINPUT",
        b's' => "SETITEM",
        b't' => "TUPLE",
        b')' => "EMPTY_TUPLE",
        b'u' => "SETITEMS",
        b'G' => "BINFLOAT",
        b'B' => "BINBYTES",
        b'C' => "SHORT_BINBYTES",
        0x80 => "PROTO",
        0x81 => "NEWOBJ",
        0x82 => "EXT1",
        0x83 => "EXT2",
        0x84 => "EXT4",
        0x85 => "TUPLE1",
        0x86 => "TUPLE2",
        0x87 => "TUPLE3",
        0x88 => "NEWTRUE",
        0x89 => "NEWFALSE",
        0x8a => "LONG1",
        0x8b => "LONG4",
        0x8c => "SHORT_BINUNICODE",
        0x8d => "BINUNICODE8",
        0x8e => "BINBYTES8",
        0x8f => "EMPTY_SET",
        0x90 => "ADDITEMS",
        0x91 => "FROZENSET",
        0x92 => "NEWOBJ_EX",
        0x93 => "STACK_GLOBAL",
        0x94 => "MEMOIZE",
        0x95 => "FRAME",
        0x96 => "BYTEARRAY8",
        0x97 => "NEXT_BUFFER",
        0x98 => "READONLY_BUFFER",
        _ => "unknown",
    }
}
