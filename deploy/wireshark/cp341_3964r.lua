-- Wireshark dissector for 3964(R) frames in the gateway's captures (link type 148, USER1).
--
-- GET /api/v1/lines/<line>/capture on a 3964(R) line writes one packet per frame: a control
-- character (STX connection request, DLE positive acknowledgement, NAK negative acknowledgement)
-- or a telegram (data with DLE doubled, DLE ETX, and in 3964R the block check character: the XOR
-- of every byte from the first data byte to ETX). Load it with
--   wireshark -X lua_script:deploy/wireshark/cp341_3964r.lua capture.pcapng
--   tshark -X lua_script:deploy/wireshark/cp341_3964r.lua -r capture.pcapng
-- or copy it into ~/.local/lib/wireshark/plugins/.

local p = Proto("cp341_3964r", "3964(R) procedure")

local STX, ETX, DLE, NAK = 0x02, 0x03, 0x10, 0x15

local f_kind = ProtoField.string("cp341_3964r.kind", "Kind")
local f_control = ProtoField.uint8("cp341_3964r.control", "Control character", base.HEX,
  { [STX] = "STX", [DLE] = "DLE", [NAK] = "NAK" })
local f_data = ProtoField.bytes("cp341_3964r.data", "Data (DLE undoubled)")
local f_len = ProtoField.uint16("cp341_3964r.length", "Data length")
local f_bcc = ProtoField.uint8("cp341_3964r.bcc", "BCC", base.HEX)
local f_bcc_ok = ProtoField.bool("cp341_3964r.bcc_ok", "BCC good")
p.fields = { f_kind, f_control, f_data, f_len, f_bcc, f_bcc_ok }

local function xor_range(tvb, from, to)
  local x = 0
  for i = from, to do
    x = bit.bxor(x, tvb(i, 1):uint())
  end
  return x
end

function p.dissector(tvb, pinfo, tree)
  local n = tvb:len()
  if n == 0 then return 0 end
  pinfo.cols.protocol = "3964R"
  local t = tree:add(p, tvb(), "3964(R)")
  local first = tvb(0, 1):uint()
  if n == 1 and (first == STX or first == DLE or first == NAK) then
    local names = { [STX] = "STX (connection request)", [DLE] = "DLE (positive acknowledgement)",
                    [NAK] = "NAK (negative acknowledgement)" }
    t:add(f_kind, "control")
    t:add(f_control, tvb(0, 1))
    pinfo.cols.info = names[first]
    return n
  end
  t:add(f_kind, "telegram")
  -- Find DLE ETX, skipping doubled DLEs; collect the data undoubled.
  local data = ByteArray.new()
  local i = 0
  local etx_at = nil
  while i < n do
    local b = tvb(i, 1):uint()
    if b == DLE and i + 1 < n then
      local c = tvb(i + 1, 1):uint()
      if c == DLE then
        data:append(ByteArray.new(string.format("%02x", DLE)))
        i = i + 2
      elseif c == ETX then
        etx_at = i + 1
        break
      else
        data:append(ByteArray.new(string.format("%02x", b)))
        i = i + 1
      end
    else
      data:append(ByteArray.new(string.format("%02x", b)))
      i = i + 1
    end
  end
  t:add(f_len, data:len())
  if data:len() > 0 then
    -- The undoubled data is not in the packet as such: it gets a data source of its own, and
    -- the field's value comes from there (a value given as a string would be taken as the
    -- characters of the string, cut to the length of the packet range).
    local undoubled = data:tvb("Data (DLE undoubled)")
    t:add(f_data, undoubled())
  end
  if etx_at == nil then
    pinfo.cols.info = string.format("telegram, %d data bytes, no DLE ETX", data:len())
    return n
  end
  if etx_at + 1 < n then
    local sum = tvb(etx_at + 1, 1):uint()
    local ok = xor_range(tvb, 0, etx_at) == sum
    t:add(f_bcc, tvb(etx_at + 1, 1))
    t:add(f_bcc_ok, ok)
    pinfo.cols.info = string.format("telegram, %d data bytes, BCC %s", data:len(), ok and "ok" or "bad")
  else
    pinfo.cols.info = string.format("telegram, %d data bytes (3964, no BCC)", data:len())
  end
  return n
end

local encaps = wtap_encaps or wtap
DissectorTable.get("wtap_encap"):add(encaps.USER1, p)
