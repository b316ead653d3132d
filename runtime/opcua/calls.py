"""Every method call of a client held to OPC UA Part 4 (5.11.2, the Call service) before
anything runs (docs/opcua.md, "Methods").

asyncua 2.1 runs a method's function with whatever ObjectId and input arguments a client
sends: ``t1.Pause`` called on the object ``t2``, or with an argument too many, ran. So each
CallMethodRequest of a client session is checked here, against the address space alone,
for every method the server exposes (the plant's, the conditions' Acknowledge and
Confirm, ConditionRefresh, the standard Server object's), and refused without running:

- an ObjectId not in the address space: BadNodeIdUnknown; not an Object or ObjectType:
  BadNodeIdInvalid;
- a MethodId that is not a Method, or not a component of that Object (of the Object
  itself, of its type or a supertype of it; of an ObjectType itself or a supertype):
  BadMethodInvalid;
- a Method whose Executable is false: BadNotExecutable; one nothing implements (asyncua
  has the standard methods without code): BadNotImplemented;
- fewer input arguments than its InputArguments property lists: BadArgumentsMissing;
  more: BadTooManyArguments (a Method without the property takes none);
- an argument of another data type, or an array where a scalar is expected (or the
  reverse): BadInvalidArgument, with BadTypeMismatch in InputArgumentResults at that
  argument and Good at the others;
- ConditionRefresh and ConditionRefresh2 naming a subscription that is not the calling
  session's: BadSubscriptionIdInvalid (Part 4: a subscription belongs to its session).

The checks are dictionary look-ups in the server's event loop, without a suspension point
(a few microseconds a call): a client sending bad calls costs the others nothing more than
any call does.
"""

from __future__ import annotations

from typing import Any

from asyncua import ua

Codes = ua.StatusCodes
_Ref = ua.ObjectIds
#: the references that make a Method a component of an Object or ObjectType
_COMPONENT = frozenset({ua.NodeId(_Ref.HasComponent), ua.NodeId(_Ref.HasOrderedComponent)})
_SUBTYPE = ua.NodeId(_Ref.HasSubtype)
_TYPE_DEFINITION = ua.NodeId(_Ref.HasTypeDefinition)
_PROPERTY = ua.NodeId(_Ref.HasProperty)
_OBJECT_CLASSES = (ua.NodeClass.Object, ua.NodeClass.ObjectType)
#: the methods whose first argument is a subscription of the calling session
_REFRESH = frozenset({ua.NodeId(_Ref.ConditionType_ConditionRefresh),
                      ua.NodeId(_Ref.ConditionType_ConditionRefresh2)})
_V = ua.VariantType
_SIGNED = frozenset({_V.SByte, _V.Int16, _V.Int32, _V.Int64})
_UNSIGNED = frozenset({_V.Byte, _V.UInt16, _V.UInt32, _V.UInt64})
#: the abstract data types an argument may have -> the variant types they take (None: any)
_ABSTRACT: dict[int, frozenset[ua.VariantType] | None] = {
    _Ref.BaseDataType: None,
    _Ref.Number: _SIGNED | _UNSIGNED | {_V.Float, _V.Double},
    _Ref.Integer: _SIGNED, _Ref.UInteger: _UNSIGNED,
    _Ref.Enumeration: frozenset({_V.Int32}),
    _Ref.Structure: frozenset({_V.ExtensionObject}),
}
#: the longest chain of supertypes followed (the standard's are a few deep)
_DEPTH = 32


def refusal(aspace: Any, session: Any, req: ua.CallMethodRequest) -> ua.CallMethodResult | None:
    """The result refusing ``req`` of ``session`` (see the module), or None to run it."""
    obj = aspace.get(req.ObjectId)
    if obj is None:
        return _result(Codes.BadNodeIdUnknown)
    if _node_class(obj) not in _OBJECT_CLASSES:
        return _result(Codes.BadNodeIdInvalid)
    method = aspace.get(req.MethodId)
    if method is None or _node_class(method) != ua.NodeClass.Method:
        return _result(Codes.BadMethodInvalid)
    if not _owners(aspace, obj) & _parents(method):
        return _result(Codes.BadMethodInvalid)
    if not _attribute(method, ua.AttributeIds.Executable, True):
        return _result(Codes.BadNotExecutable)
    if method.call is None:
        return _result(Codes.BadNotImplemented)
    given = list(req.InputArguments or [])
    wanted = _input_arguments(aspace, method)
    if len(given) < len(wanted):
        return _result(Codes.BadArgumentsMissing)
    if len(given) > len(wanted):
        return _result(Codes.BadTooManyArguments)
    fits = [_fits(aspace, a, v) for a, v in zip(wanted, given, strict=True)]
    if not all(fits):
        res = _result(Codes.BadInvalidArgument)
        res.InputArgumentResults = [ua.StatusCode(Codes.Good if ok else Codes.BadTypeMismatch)
                                    for ok in fits]
        return res
    if req.MethodId in _REFRESH and not _own_subscription(session, given[0]):
        return _result(Codes.BadSubscriptionIdInvalid)
    return None


def _result(code: int) -> ua.CallMethodResult:
    res = ua.CallMethodResult()
    res.StatusCode = ua.StatusCode(code)
    return res


def _attribute(node: Any, attr: ua.AttributeIds, default: Any) -> Any:
    held = node.attributes.get(attr)
    if held is None or held.value is None or held.value.Value is None:
        return default
    return held.value.Value.Value


def _node_class(node: Any) -> Any:
    return _attribute(node, ua.AttributeIds.NodeClass, None)


def _targets(node: Any, ref_types: frozenset[ua.NodeId] | ua.NodeId, forward: bool
             ) -> list[ua.NodeId]:
    kinds = ref_types if isinstance(ref_types, frozenset) else frozenset({ref_types})
    return [r.NodeId for r in node.references
            if r.ReferenceTypeId in kinds and bool(r.IsForward) is forward]


def _parents(method: Any) -> set[ua.NodeId]:
    """The Objects and ObjectTypes ``method`` is a component of."""
    return set(_targets(method, _COMPONENT, forward=False))


def _supertypes(aspace: Any, type_id: ua.NodeId) -> list[ua.NodeId]:
    """``type_id`` and its supertypes, nearest first."""
    out = [type_id]
    for _ in range(_DEPTH):
        node = aspace.get(out[-1])
        up = _targets(node, _SUBTYPE, forward=False) if node is not None else []
        if not up or up[0] in out:
            break
        out.append(up[0])
    return out


def _owners(aspace: Any, obj: Any) -> set[ua.NodeId]:
    """Where a Method callable on ``obj`` may be a component: the Object and its type
    with the supertypes, or the ObjectType and its supertypes (Part 4, 5.11.2.2)."""
    if _node_class(obj) == ua.NodeClass.ObjectType:
        return set(_supertypes(aspace, obj.nodeid))
    out = {obj.nodeid}
    for type_id in _targets(obj, _TYPE_DEFINITION, forward=True):
        out.update(_supertypes(aspace, type_id))
    return out


def _input_arguments(aspace: Any, method: Any) -> list[ua.Argument]:
    """The Arguments of ``method``'s InputArguments property ([] without one)."""
    for prop_id in _targets(method, _PROPERTY, forward=True):
        prop = aspace.get(prop_id)
        if prop is None:
            continue
        name = _attribute(prop, ua.AttributeIds.BrowseName, None)
        if getattr(name, "Name", None) == "InputArguments":
            return list(_attribute(prop, ua.AttributeIds.Value, None) or [])
    return []


def _accepted(aspace: Any, data_type: ua.NodeId) -> frozenset[ua.VariantType] | None:
    """The variant types a value of ``data_type`` may have (None: any): its built-in type,
    found through its supertypes (Duration is a Double, IntegerId a UInt32)."""
    for type_id in _supertypes(aspace, data_type):
        if type_id.NamespaceIndex != 0 or not isinstance(type_id.Identifier, int):
            continue
        if type_id.Identifier in _ABSTRACT:
            return _ABSTRACT[type_id.Identifier]
        try:
            return frozenset({ua.VariantType(type_id.Identifier)})
        except ValueError:
            continue
    return None  # a type of no built-in base: not checked


def _fits(aspace: Any, arg: ua.Argument, value: Any) -> bool:
    """Whether ``value`` (a Variant) is of ``arg``'s data type and rank."""
    if not isinstance(value, ua.Variant):
        return False
    array = bool(value.is_array)
    rank = arg.ValueRank
    if (rank == -1 and array) or (rank >= 0 and not array):
        return False
    accepted = _accepted(aspace, arg.DataType)
    return accepted is None or value.VariantType in accepted


def _own_subscription(session: Any, arg: ua.Variant) -> bool:
    """Whether the subscription ``arg`` names is one of ``session``'s."""
    subs = session.subscription_service.subscriptions
    sub = subs.get(arg.Value)
    return sub is not None and sub.session_id == session.session_id
