// An OPC UA client not built on asyncua: node-opcua (a separate implementation, in
// TypeScript). Run by tests/opcua/test_foreign_client.py with one JSON argument:
//   {endpoint, mode: "None"|"SignAndEncrypt", cert, key, serverCert, pki, user, password,
//    browse: [nodeId...], read: [nodeId...], subscribe: [nodeId...], seconds,
//    write: {nodeId, value, type: "Boolean"|"Double"}}
// It prints one JSON object per line: {"browse": nodeId, "children": [[name, nodeId]...]},
// {"read": nodeId, "value", "type", "status", "source_ms"}, {"publish": seq, "items":
// [[clientHandle, value, source_ms, status]...]}, {"handles": {clientHandle: nodeId}},
// {"write": nodeId, "status"}, {"done": true};
// {"error": text} and exit 1 on a failure.
"use strict";
const fs = require("fs");
const path = require("path");
const {
  OPCUAClient, MessageSecurityMode, SecurityPolicy, AttributeIds, TimestampsToReturn,
  UserTokenType, ClientSubscription, ClientMonitoredItem, DataType, Variant,
} = require("node-opcua-client");
const { OPCUACertificateManager } = require("node-opcua-certificate-manager");

const cfg = JSON.parse(process.argv[2]);
const out = (obj) => process.stdout.write(JSON.stringify(obj) + "\n");
const ms = (d) => (d ? d.getTime() : null);
// node-opcua gives a 64-bit integer as [high, low] 32-bit words
const value = (variant) => {
  const v = variant.value;
  if ((variant.dataType === DataType.Int64 || variant.dataType === DataType.UInt64) &&
      Array.isArray(v)) {
    return v[0] * 4294967296 + v[1];
  }
  return v;
};

async function main() {
  const secure = cfg.mode === "SignAndEncrypt";
  const options = {
    applicationName: "softplc foreign test client",
    endpointMustExist: false,
    connectionStrategy: { maxRetry: 2, initialDelay: 200, maxDelay: 1000 },
    securityMode: secure ? MessageSecurityMode.SignAndEncrypt : MessageSecurityMode.None,
    securityPolicy: secure ? SecurityPolicy.Basic256Sha256 : SecurityPolicy.None,
  };
  // its own PKI folder: the server's certificate is trusted explicitly, nothing else
  const manager = new OPCUACertificateManager({
    rootFolder: cfg.pki, automaticallyAcceptUnknownCertificate: false,
  });
  await manager.initialize();
  if (cfg.serverCert) {
    await manager.trustCertificate(fs.readFileSync(cfg.serverCert));
  }
  options.clientCertificateManager = manager;
  if (cfg.cert) {
    options.certificateFile = cfg.cert;
    options.privateKeyFile = cfg.key;
    options.applicationUri = cfg.applicationUri;
  }
  const client = OPCUAClient.create(options);
  await client.connect(cfg.endpoint);
  const identity = cfg.user
    ? { type: UserTokenType.UserName, userName: cfg.user, password: cfg.password }
    : { type: UserTokenType.Anonymous };
  const session = await client.createSession(identity);
  try {
    for (const nodeId of cfg.browse || []) {
      const res = await session.browse(nodeId);
      out({ browse: nodeId, status: res.statusCode.name,
            children: res.references.map((r) => [r.browseName.name, r.nodeId.toString()]) });
    }
    for (const nodeId of cfg.read || []) {
      const dv = await session.read({ nodeId, attributeId: AttributeIds.Value });
      out({ read: nodeId, value: value(dv.value), type: DataType[dv.value.dataType],
            status: dv.statusCode.name, source_ms: ms(dv.sourceTimestamp) });
    }
    if (cfg.write) {
      // a refused service (a ServiceFault, not a per-node status) throws: its status code
      // is the write's status
      let status;
      try {
        status = (await session.write({
          nodeId: cfg.write.nodeId, attributeId: AttributeIds.Value,
          value: { value: new Variant({ dataType: DataType[cfg.write.type || "Boolean"],
                                        value: cfg.write.value }) },
        })).name;
      } catch (err) {
        const m = /Bad[A-Za-z]+/.exec(String(err && err.message));
        status = m ? m[0] : `error: ${err}`;
      }
      out({ write: cfg.write.nodeId, status });
    }
    if ((cfg.subscribe || []).length) {
      const sub = ClientSubscription.create(session, {
        requestedPublishingInterval: 100, requestedLifetimeCount: 600,
        requestedMaxKeepAliveCount: 20, maxNotificationsPerPublish: 0,
        publishingEnabled: true, priority: 1,
      });
      const handles = {};
      sub.on("raw_notification", (msg) => {
        const items = [];
        for (const nd of msg.notificationData || []) {
          for (const mi of nd.monitoredItems || []) {
            const dv = mi.value;
            items.push([mi.clientHandle, value(dv.value),
                        ms(dv.sourceTimestamp), dv.statusCode.name]);
          }
        }
        if (items.length) out({ publish: msg.sequenceNumber, items });
      });
      for (const nodeId of cfg.subscribe) {
        const item = ClientMonitoredItem.create(
          sub, { nodeId, attributeId: AttributeIds.Value },
          { samplingInterval: 100, discardOldest: true, queueSize: 1 },
          TimestampsToReturn.Both);
        await new Promise((resolve, reject) => {
          item.once("initialized", resolve);
          item.once("err", (e) => reject(new Error(`${nodeId}: ${e}`)));
        });
        handles[item.monitoringParameters.clientHandle] = nodeId;
      }
      await new Promise((resolve) => setTimeout(resolve, cfg.seconds * 1000));
      await sub.terminate();
      out({ handles });
    }
  } finally {
    await session.close();
    await client.disconnect();
  }
  out({ done: true });
}

main().then(() => process.exit(0), (err) => {
  out({ error: String(err && err.message ? err.message : err) });
  process.exit(1);
});
