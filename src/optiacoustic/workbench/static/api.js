// Talking to the workbench server: JSON in, JSON out; the per-run token (if any) rides along.
const token = new URLSearchParams(location.search).get("token");

export function withToken(url) {
  if (!token) return url;
  return url + (url.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(token);
}

async function request(method, url, body) {
  const opts = { method, headers: {} };
  if (token) opts.headers["X-Workbench-Token"] = token;
  if (body !== undefined) {
    opts.headers["Content-Type"] = "application/json";
    opts.body = JSON.stringify(body);
  }
  const resp = await fetch(url, opts);
  const type = resp.headers.get("content-type") || "";
  const data = type.includes("json") ? await resp.json() : await resp.text();
  if (!resp.ok) {
    let msg = data && data.error ? data.error : data && data.detail ? JSON.stringify(data.detail) : String(data);
    throw new Error(msg);
  }
  return data;
}

export const get = (url) => request("GET", url);
export const post = (url, body) => request("POST", url, body === undefined ? {} : body);
export const put = (url, body) => request("PUT", url, body);
export const del = (url) => request("DELETE", url);
