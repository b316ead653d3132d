// An OPC UA alarm client not built on asyncua (node-opcua), driven line by line by
// tests/opcua/test_alarms.py. One JSON argument: {endpoint, user, password}. It subscribes
// to the events of the Server object and prints each one, then runs the commands it reads
// on stdin, one JSON object a line, printing one JSON answer each:
//   {"refresh": true}                                  -> {"refresh": status}
//   {"ack": conditionId, "eventId": hex, "comment": s}  -> {"ack": status}
//   {"confirm": conditionId, "eventId": hex, "comment": s} -> {"confirm": status}
//   {"call": objectId, "method": methodId, "args": [[dataType, value], ...]}
//                          -> {"call": status}, with "inputs": [status...] when there are some
//   {"executable": nodeId}                              -> {"executable": UserExecutable}
//   {"quit": true}
// Events: {"event": {EventId (hex), ConditionId, ConditionName, SourceName, Message,
// Severity, Retain, Active, Acked, Confirmed, Comment, ClientUserId, EventType}}.
// Errors: {"error": text} and exit 1.
"use strict";
const readline = require("readline");
const {
  OPCUAClient, MessageSecurityMode, SecurityPolicy, AttributeIds, UserTokenType,
  ClientSubscription, ClientMonitoredItem, TimestampsToReturn, constructEventFilter,
  callConditionRefresh, acknowledgeCondition, confirmCondition, DataType, Variant,
} = require("node-opcua-client");

const cfg = JSON.parse(process.argv[2]);
const out = (obj) => process.stdout.write(JSON.stringify(obj) + "\n");
const FIELDS = ["EventId", "ConditionId", "ConditionName", "SourceName", "Message", "Severity",
                "Retain", "ActiveState.Id", "AckedState.Id", "ConfirmedState.Id", "Comment",
                "ClientUserId", "EventType"];
const text = (v) => (v && v.value !== null && v.value !== undefined
  ? (v.value.text !== undefined ? v.value.text : v.value) : null);

async function main() {
  const client = OPCUAClient.create({
    endpointMustExist: false, securityMode: MessageSecurityMode.None,
    securityPolicy: SecurityPolicy.None,
    connectionStrategy: { maxRetry: 2, initialDelay: 200, maxDelay: 1000 },
  });
  await client.connect(cfg.endpoint);
  const identity = cfg.user
    ? { type: UserTokenType.UserName, userName: cfg.user, password: cfg.password }
    : { type: UserTokenType.Anonymous };
  const session = await client.createSession(identity);
  const sub = ClientSubscription.create(session, {
    requestedPublishingInterval: 100, requestedLifetimeCount: 600,
    requestedMaxKeepAliveCount: 20, maxNotificationsPerPublish: 0, publishingEnabled: true,
    priority: 1,
  });
  await new Promise((resolve) => sub.once("started", resolve));
  const item = ClientMonitoredItem.create(
    sub, { nodeId: "ns=0;i=2253", attributeId: AttributeIds.EventNotifier },
    { samplingInterval: 0, discardOldest: true, queueSize: 100,
      filter: constructEventFilter(FIELDS) }, TimestampsToReturn.Neither);
  item.on("changed", (values) => {
    const e = {};
    FIELDS.forEach((f, k) => { e[f] = values[k]; });
    out({ event: {
      EventId: e.EventId.value ? Buffer.from(e.EventId.value).toString("hex") : null,
      ConditionId: e.ConditionId.value ? e.ConditionId.value.toString() : null,
      ConditionName: text(e.ConditionName), SourceName: text(e.SourceName),
      Message: text(e.Message), Severity: text(e.Severity), Retain: text(e.Retain),
      Active: text(e["ActiveState.Id"]), Acked: text(e["AckedState.Id"]),
      Confirmed: text(e["ConfirmedState.Id"]), Comment: text(e.Comment),
      ClientUserId: text(e.ClientUserId),
      EventType: e.EventType.value ? e.EventType.value.toString() : null,
    } });
  });
  await new Promise((resolve, reject) => {
    item.once("initialized", resolve);
    item.once("err", (err) => reject(new Error(String(err))));
  });
  out({ ready: true, subscription: sub.subscriptionId });
  const rl = readline.createInterface({ input: process.stdin });
  for await (const line of rl) {
    const cmd = JSON.parse(line);
    if (cmd.quit) break;
    if (cmd.refresh) {
      out({ refresh: (await callConditionRefresh(session, sub.subscriptionId)).name });
    } else if (cmd.ack || cmd.confirm) {
      const verb = cmd.ack ? "ack" : "confirm";
      const fn = cmd.ack ? acknowledgeCondition : confirmCondition;
      const status = await fn(session, cmd[verb], Buffer.from(cmd.eventId, "hex"),
                              cmd.comment || "");
      out({ [verb]: status.name });
    } else if (cmd.call) {
      const inputArguments = (cmd.args || []).map(
        ([type, value]) => new Variant({ dataType: DataType[type], value }));
      const res = await session.call({ objectId: cmd.call, methodId: cmd.method,
                                       inputArguments });
      const inputs = (res.inputArgumentResults || []).map((s) => s.name);
      out(inputs.length ? { call: res.statusCode.name, inputs } : { call: res.statusCode.name });
    } else if (cmd.executable) {
      const dv = await session.read({ nodeId: cmd.executable,
                                      attributeId: AttributeIds.UserExecutable });
      out({ executable: dv.value.value, status: dv.statusCode.name });
    }
  }
  await sub.terminate();
  await session.close();
  await client.disconnect();
  out({ done: true });
}

main().then(() => process.exit(0), (err) => {
  out({ error: String(err && err.message ? err.message : err) });
  process.exit(1);
});
